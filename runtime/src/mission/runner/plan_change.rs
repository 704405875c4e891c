//! Plan changes from the observers (a ground station's `qosrt fleet set`): each is turned into
//! the governor's [`PlanChange`], applied whole or refused whole, and answered.

use super::{MissionRunner, RunnerError};
use crate::governor::{GovernorEvent, PlanChange, PlanChangeError, ReplanSummary};
use crate::mission::observer::{PlanAnswer, PlanRequest};
use crate::scheduler::TaskScheduler;
use crate::telemetry::MissionProgress;

impl<S: TaskScheduler> MissionRunner<S> {
    /// The plan changes the observers were asked for, each recorded, applied and answered: the
    /// governor re-plans at once, or the change is refused by name and nothing changes. Taken
    /// before the step is recorded, so a replay hands each to the step that took it.
    pub(super) fn take_plan_requests(&mut self, now_s: f64) -> Result<(), RunnerError> {
        let requests: Vec<PlanRequest> = self
            .observers
            .iter()
            .flat_map(|o| o.plan_requests(now_s))
            .collect();
        for request in requests {
            if let Some(recorder) = &self.recorder {
                recorder.plan_request(now_s, &request);
            }
            let refusal = match self.change_plan(now_s, &request) {
                Ok(decisions) => {
                    self.note(now_s, describe(&request));
                    self.take_decisions(now_s, decisions)?;
                    None
                }
                Err(error) => {
                    self.note(
                        now_s,
                        format!("plan change {} refused: {error}", request.id),
                    );
                    Some(error.to_string())
                }
            };
            let answer = self.plan_answer(now_s, request.id, refusal);
            for observer in &self.observers {
                observer.plan_answer(&answer);
            }
            // The status shows the change at once, not at its next second.
            self.observed_tasks = None;
        }
        Ok(())
    }

    fn change_plan(
        &mut self,
        now_s: f64,
        request: &PlanRequest,
    ) -> Result<Vec<GovernorEvent>, PlanChangeError> {
        let progress = self.progress_at(now_s);
        let plan = self.sequencer.plan();
        let phase_durations_s = match request.time_left_s {
            Some(time_left_s) => {
                let timed: Vec<bool> = (0..plan.phase_names.len())
                    .map(|phase| plan.ends_by_duration(phase))
                    .collect();
                self.governor
                    .durations_for_time_left(progress, time_left_s, &timed)?
            }
            None => Vec::new(),
        };
        let change = PlanChange {
            reserve_fraction: request.reserve_fraction,
            phase_durations_s,
            allowed_levels: request.levels.clone(),
        };
        let decisions = self.governor.change_plan(&change)?;
        self.sequencer
            .set_phase_durations(&change.phase_durations_s);
        Ok(decisions)
    }

    /// Where the mission is, as the sequencer has it now.
    pub(super) fn progress_at(&self, now_s: f64) -> MissionProgress {
        let status = self.sequencer.status();
        status.phase.map_or(MissionProgress::start(), |phase| {
            MissionProgress::new(phase, now_s - status.phase_started_s)
        })
    }

    fn plan_answer(&self, now_s: f64, id: u64, refusal: Option<String>) -> PlanAnswer {
        let tasks = &self.governor.problem().tasks;
        PlanAnswer {
            id,
            accepted: refusal.is_none(),
            refusal,
            reserve_fraction: self.governor.reserve_fraction(),
            margin_wh: self
                .governor
                .last_replan()
                .map(ReplanSummary::end_margin_wh),
            land_now: self.governor.land_now_raised(),
            levels: self.named_levels(&self.with_fixed(self.governor.current_levels())),
            time_left_s: Some(self.governor.planned_time_left_s(self.progress_at(now_s))),
            allowed_levels: tasks
                .iter()
                .filter_map(|task| task.allowed_levels.map(|range| (task.name.clone(), range)))
                .collect(),
        }
    }
}

/// The change as the mission's log tells it.
fn describe(request: &PlanRequest) -> String {
    let mut parts = Vec::new();
    if let Some(reserve) = request.reserve_fraction {
        parts.push(format!("reserve {reserve:.2}"));
    }
    if let Some(time_left_s) = request.time_left_s {
        parts.push(format!("time left {time_left_s:.0} s"));
    }
    for (task, range) in &request.levels {
        parts.push(match range {
            Some(range) => format!("{task} levels {}..={}", range.min, range.max),
            None => format!("{task} levels unbounded"),
        });
    }
    format!("plan changed in flight: {}", parts.join(", "))
}
