//! What the runner tells its observers (a ROS 2 node, a ground station): the plan and its
//! forecast after each re-plan, the tasks' levels and statistics, and the mission at a glance.

use super::{MissionRunner, OBSERVED_TASKS_PERIOD_S};
use crate::governor::ReplanSummary;
use crate::mission::observer::{MissionObserver, PlanForecast, PlannedPhase, VehicleStatus};
use crate::scheduler::TaskScheduler;

impl<S: TaskScheduler> MissionRunner<S> {
    /// Tells `observer` what the mission does from now on.
    pub fn observe(&mut self, mut observer: Box<dyn MissionObserver>) {
        observer.watch_bus(self.scheduler.bus());
        self.observers.push(observer);
    }

    /// The plan and forecast of the last re-plan, for the observers, once per re-plan.
    pub(super) fn observe_plan(&mut self, now_s: f64) {
        // Before the first re-plan: the plan the governor started from, for a full pack.
        let (time_s, trigger, remaining_energy_wh, needed_wh, margin_wh, sigma_wh) =
            match self.governor.last_replan() {
                Some(replan) => (
                    replan.time_s,
                    replan.trigger.to_string(),
                    replan.remaining_energy_wh,
                    replan.needed_wh,
                    replan.end_margin_wh(),
                    replan.sigma_wh,
                ),
                None => {
                    let plan = self.governor.initial_plan();
                    let usable_wh = self.governor.usable_full_wh();
                    let available_wh = usable_wh * (1.0 - self.governor.reserve_fraction());
                    (
                        now_s,
                        "the plan for a full pack".to_string(),
                        usable_wh,
                        plan.energy_wh,
                        available_wh - plan.energy_wh,
                        0.0,
                    )
                }
            };
        let replanned_at = self.governor.last_replan().map(|r| r.time_s);
        if self.observed_replan_s.is_some() && self.observed_replan_s == Some(replanned_at) {
            return;
        }
        self.observed_replan_s = Some(replanned_at);
        let first = self.governor.planned_levels();
        let phase_in_flight = self.model.config.mission.phases.len() - first.len();
        let phases = first
            .iter()
            .enumerate()
            .map(|(offset, levels)| PlannedPhase {
                name: self.model.config.mission.phases[phase_in_flight + offset]
                    .name
                    .clone(),
                levels: self
                    .named_levels(levels)
                    .tasks
                    .into_iter()
                    .map(|(task, level)| (task, level.level))
                    .collect(),
            })
            .collect();
        let plan = PlanForecast {
            time_s,
            trigger,
            reserve_fraction: self.governor.reserve_fraction(),
            remaining_energy_wh,
            needed_wh,
            margin_wh,
            sigma_wh,
            phases,
        };
        for observer in &self.observers {
            observer.plan(&plan);
        }
    }

    /// The tasks' levels and statistics for the observers: when a level changes, and once a
    /// second.
    pub(super) fn observe_tasks(&mut self, now_s: f64) {
        if self.observers.is_empty() {
            return;
        }
        self.observe_plan(now_s);
        let levels = self.with_fixed(self.governor.current_levels());
        if let Some((observed, at_s)) = &self.observed_tasks {
            if *observed == levels && now_s - at_s < OBSERVED_TASKS_PERIOD_S {
                return;
            }
        }
        let (named, stats) = (self.named_levels(&levels), self.scheduler.stats());
        let status = self.vehicle_status(now_s);
        for observer in &self.observers {
            observer.tasks(now_s, &named, &stats);
            observer.status(&status);
        }
        self.observed_tasks = Some((levels, now_s));
    }

    /// The mission at a glance, for the observers (a fleet's ground station).
    fn vehicle_status(&self, now_s: f64) -> VehicleStatus {
        let replan = self.governor.last_replan();
        let power_w = self
            .phase
            .and_then(|phase| self.governor.model_power_w(phase))
            .map(|w| w * self.governor.correction_ratio());
        VehicleStatus {
            time_s: now_s,
            phase: self
                .phase
                .map(|index| self.model.config.mission.phases[index].name.clone()),
            battery_fraction: self.log.battery.last.and_then(|b| b.remaining_fraction),
            reserve_fraction: self.governor.reserve_fraction(),
            margin_wh: replan.map(ReplanSummary::end_margin_wh),
            available_wh: replan.map(|r| r.available_wh),
            // What is left above the reserve, at the power the levels in force draw.
            flight_time_left_s: replan
                .zip(power_w)
                .filter(|(_, w)| *w > 0.0)
                .map(|(r, w)| r.available_wh.max(0.0) / w * 3600.0),
            mission_time_left_s: self
                .phase
                .map(|_| self.governor.planned_time_left_s(self.progress_at(now_s))),
            land_now: self.governor.land_now_raised(),
            levels: self
                .named_levels(&self.with_fixed(self.governor.current_levels()))
                .tasks
                .into_iter()
                .map(|(task, level)| (task, level.level))
                .collect(),
            last_event: self.log.events.last().map(|(_, event)| event.clone()),
        }
    }
}
