//! The mission runner: the one loop that flies a mission, onboard and in simulation.
//!
//! Each [`MissionRunner::step`] runs, at the clock's `now`: the link (telemetry in), the
//! governor (battery telemetry → QoS levels), the camera (frames in, stamped at capture), the
//! scheduler (the tasks of the current phase), the sequencer (phases, commands) and the link
//! again (commands out). What drives it is the caller's: `qosrt run` calls it on the wall
//! clock with a [`RealTimeScheduler`](crate::scheduler::RealTimeScheduler), the simulator's
//! harness in lockstep with its world on a [`VirtualScheduler`](crate::scheduler::VirtualScheduler).

use super::input_rates::InputRateMeter;
use super::observer::MissionObserver;
use super::report::MissionLog;
use super::sequencer::{
    AutopilotView, MissionEvent, MissionPlan, MissionSequencer, MissionStatus, PhaseKind,
    SequencerInput,
};
use crate::bus::{Publisher, Subscriber};
use crate::camera::CameraSource;
use crate::clock::Timestamp;
use crate::energy::MissionModel;
use crate::governor::GovernorDecision;
use crate::governor::{Governor, GovernorError, GovernorEvent};
use crate::link::{FailsafeAction, LinkError, LinkStatus, LinkUpdate, MavlinkLink, VehicleCommand};
use crate::record::channels::StepRecord;
use crate::record::recorder::{BatteryEstimate, QosLevels, TaskLevelRecord};
use crate::record::{RecordError, Recorder, RecordingSummary};
use crate::scheduler::{PhaseGate, SchedulerError, TaskId, TaskScheduler};
use crate::topics::{
    CameraFrame, LandingSetpoint, MissionPhase, RelativeState, VehicleState, CAMERA_FRAME,
    LANDING_SETPOINT, MISSION_PHASE, RELATIVE_STATE, VEHICLE_STATE,
};
use algorithms::estimation::attitude_history::{AttitudeHistory, AttitudeSample};
use power_models::planner::TaskLevel;
use std::sync::Arc;
use std::time::Duration;

mod observers;
mod plan_change;
mod vision;

/// The telemetry the loop flies on, with the rate it asks the autopilot for (MAVLink message
/// id, Hz): PX4 sends BATTERY_STATUS at 0.5 Hz on its onboard link, ArduPilot nothing at all
/// until asked.
pub const TELEMETRY_STREAMS: [(u32, f64); 7] = [
    (30, 50.0),  // ATTITUDE
    (32, 50.0),  // LOCAL_POSITION_NED
    (132, 20.0), // DISTANCE_SENSOR
    (245, 5.0),  // EXTENDED_SYS_STATE
    (147, 2.0),  // BATTERY_STATUS
    (1, 2.0),    // SYS_STATUS
    (33, 5.0),   // GLOBAL_POSITION_INT
];
/// The stream requests are sent this many times, this far apart, once the autopilot is heard
/// (a request lost on a radio link is not fatal).
/// How much vehicle history frames are matched against: a frame reaches the runner well
/// within this of its exposure (a camera pipeline's latency is tens of milliseconds).
const VEHICLE_HISTORY_S: f64 = 2.0;
const STREAM_REQUESTS: u32 = 3;
const STREAM_REQUEST_PERIOD_S: f64 = 5.0;

/// A landing setpoint older than this no longer steers.
pub const SETPOINT_MAX_AGE_S: f64 = 0.5;

/// Frames whose arrival is remembered: a fix comes from one of the last few.
const ARRIVALS_KEPT: usize = 16;
/// How often the observers hear the tasks' statistics when no level changes.
const OBSERVED_TASKS_PERIOD_S: f64 = 1.0;
/// How long a lockstep poll waits for the simulated autopilot (wall clock).
pub const LOCKSTEP_TIMEOUT: Duration = Duration::from_secs(5);

#[derive(Debug, thiserror::Error)]
pub enum RunnerError {
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error(transparent)]
    Link(#[from] LinkError),
    #[error("governor: {0}")]
    Governor(#[source] GovernorError),
    #[error("bus: {0}")]
    Bus(#[from] crate::bus::BusError),
    #[error("--fix {task}={value}: {why}")]
    FixedLevel {
        task: String,
        value: f64,
        why: String,
    },
}

/// How the runner flies.
#[derive(Debug, Clone, Default)]
pub struct RunnerOptions {
    /// Send LANDING_TARGET from the tracker's estimate, for the autopilot's own precision
    /// landing.
    pub landing_target: bool,
    /// Tasks held at the level whose knob value is given (the governor leaves them alone).
    pub fixed_levels: Vec<(String, f64)>,
}

/// What one step did.
#[derive(Debug, Clone)]
pub struct StepReport {
    pub link: LinkStatus,
    pub commands: Vec<VehicleCommand>,
    pub events: Vec<MissionEvent>,
    /// The landing task's setpoint that steered this step.
    pub landing: Option<LandingSetpoint>,
}

/// The loop's state: link, governor, scheduler, sequencer, camera.
pub struct MissionRunner<S: TaskScheduler> {
    model: MissionModel,
    scheduler: S,
    /// The scheduler's id of every config task, indexed like `config.tasks`; `None` for a task
    /// the scheduler does not hold (its plugin is not built in).
    task_ids: Vec<Option<TaskId>>,
    governor: Governor,
    fixed: Vec<(usize, usize)>,
    link: MavlinkLink,
    sequencer: MissionSequencer,
    camera: Option<Box<dyn CameraSource>>,
    /// The vision fix whose latency was last recorded.
    last_timed_fix_s: Option<f64>,
    /// The landing task's last mode.
    last_landing_mode: Option<algorithms::control::landing::LandingMode>,
    /// The camera's counters when it ended.
    ended_camera_stats: Option<crate::camera::CameraStats>,
    options: RunnerOptions,
    vehicle_topic: Publisher<VehicleState>,
    phase_topic: Publisher<MissionPhase>,
    frames: Publisher<CameraFrame>,
    /// The index of the frame on the camera topic, for the recording's word on whether a task
    /// read it.
    frame_on_topic: Option<u64>,
    /// The vehicle's recent states, to hand each frame the one at its exposure.
    vehicle_history: AttitudeHistory,
    /// The last frames' capture and arrival times, to tell the runtime's own delay.
    arrivals: std::collections::VecDeque<(f64, f64)>,
    setpoints: Subscriber<LandingSetpoint>,
    relative: Subscriber<RelativeState>,
    phase: Option<usize>,
    land_now: Option<&'static str>,
    log: MissionLog,
    started: bool,
    /// Stream requests sent so far, and when the last went.
    stream_requests: (u32, f64),
    /// Where the run is recorded, if it is, and the levels it last recorded.
    recorder: Option<Recorder>,
    recorded_levels: Option<Vec<TaskLevel>>,
    /// Who else hears of the mission (the ROS 2 node), the levels they last heard, and when.
    observers: Vec<Box<dyn MissionObserver>>,
    observed_tasks: Option<(Vec<TaskLevel>, f64)>,
    /// The re-plan the observers last heard of (`Some(None)`: the plan for a full pack).
    observed_replan_s: Option<Option<f64>>,
    /// How often the topics that trigger tasks deliver, and their publish counters.
    input_rates: InputRateMeter,
    input_activity: Vec<std::sync::Arc<crate::bus::TopicActivity>>,
}

impl<S: TaskScheduler> MissionRunner<S> {
    /// A runner over a built (not started) scheduler and an open link. Tasks stay suspended
    /// until the sequencer starts the first phase.
    pub fn new(
        model: MissionModel,
        scheduler: S,
        link: MavlinkLink,
        plan: MissionPlan,
        camera: Option<Box<dyn CameraSource>>,
        options: RunnerOptions,
    ) -> Result<Self, RunnerError> {
        let governor =
            Governor::from_mission(&model, model.config.governor.clone().unwrap_or_default())
                .map_err(RunnerError::Governor)?;
        let fixed = resolve_fixed_levels(&model, &options.fixed_levels)?;
        let task_ids = model
            .config
            .tasks
            .iter()
            .map(|task| scheduler.task_id(&task.name))
            .collect();
        let bus = scheduler.bus().clone();
        let mut trigger_topics: Vec<String> = model
            .config
            .tasks
            .iter()
            .filter_map(|task| task.trigger.input().map(str::to_string))
            .collect();
        trigger_topics.sort();
        trigger_topics.dedup();
        let input_activity = trigger_topics
            .iter()
            .map(|topic| bus.activity(topic))
            .collect::<Result<_, _>>()?;
        let input_rates = InputRateMeter::new(trigger_topics, model.declared_input_rates());
        Ok(Self {
            input_rates,
            input_activity,
            vehicle_topic: bus.publisher(VEHICLE_STATE)?,
            phase_topic: bus.publisher(MISSION_PHASE)?,
            frames: bus.publisher(CAMERA_FRAME)?,
            frame_on_topic: None,
            arrivals: std::collections::VecDeque::with_capacity(ARRIVALS_KEPT),
            vehicle_history: AttitudeHistory::new(VEHICLE_HISTORY_S),
            setpoints: bus.subscriber(LANDING_SETPOINT)?,
            relative: bus.subscriber(RELATIVE_STATE)?,
            model,
            scheduler,
            task_ids,
            governor,
            fixed,
            link,
            sequencer: MissionSequencer::new(plan),
            camera,
            ended_camera_stats: None,
            last_landing_mode: None,
            last_timed_fix_s: None,
            options,
            phase: None,
            land_now: None,
            log: MissionLog::default(),
            started: false,
            stream_requests: (0, f64::NEG_INFINITY),
            recorder: None,
            recorded_levels: None,
            observers: Vec::new(),
            observed_tasks: None,
            observed_replan_s: None,
        })
    }

    /// Records the run from now on: what the link receives and sends, the frames, every
    /// recorded bus topic, governor decisions, levels, battery and events.
    pub fn record(&mut self, recorder: Recorder) -> Result<(), RunnerError> {
        recorder.tap_bus(self.scheduler.bus())?;
        self.link.start_capture();
        self.recorder = Some(recorder);
        Ok(())
    }

    /// Ends the recording (after [`Self::stop`]: the tasks' statistics go in last).
    pub fn finish_recording(&mut self) -> Option<Result<RecordingSummary, RecordError>> {
        let recorder = self.recorder.take()?;
        if let (Some(index), Some(read)) = (self.frame_on_topic, self.frames.current_read()) {
            recorder.frame_read(index, read);
        }
        recorder.task_stats(self.scheduler.now().as_secs_f64(), self.scheduler.stats());
        Some(recorder.finish())
    }

    /// A mission event: in the run's log, and in the recording.
    fn note(&mut self, now_s: f64, text: String) {
        if let Some(recorder) = &self.recorder {
            recorder.event(now_s, text.clone());
        }
        self.log.event(now_s, text);
    }

    /// The level (and knob value) every task runs at now: fixed, else the governor's.
    pub fn qos_levels(&self) -> QosLevels {
        self.named_levels(&self.with_fixed(self.governor.current_levels()))
    }

    /// `levels` by task name, with their knob values.
    fn named_levels(&self, levels: &[TaskLevel]) -> QosLevels {
        QosLevels {
            tasks: levels
                .iter()
                .filter_map(|l| {
                    let task = self.model.config.tasks.get(l.task)?;
                    Some((
                        task.name.clone(),
                        TaskLevelRecord {
                            level: l.level,
                            value: *task.levels.get(l.level)?,
                        },
                    ))
                })
                .collect(),
        }
    }

    /// What this step gave the recording: the link's traffic, the levels if they changed, and
    /// the step itself (last: a replay runs a step once its inputs are in).
    fn record_step(&mut self, now_s: f64, lockstep: Option<u64>) {
        let Some(recorder) = &self.recorder else {
            return;
        };
        recorder.link(now_s, self.link.take_capture());
        let levels = self.with_fixed(self.governor.current_levels());
        if self.recorded_levels.as_ref() != Some(&levels) {
            recorder.levels(now_s, self.named_levels(&levels));
            self.recorded_levels = Some(levels);
        }
        recorder.step(StepRecord {
            now_s,
            lockstep_ns: lockstep,
        });
    }

    /// One turn of the loop at `now_s`. `lockstep`: the simulated autopilot's tick (its
    /// TIMESYNC barrier, in ns); `None` on the wall clock.
    pub fn step(&mut self, now_s: f64, lockstep: Option<u64>) -> Result<StepReport, RunnerError> {
        let started = std::time::Instant::now();
        let now = Timestamp::from_secs_f64(now_s);
        if !self.started {
            self.scheduler.set_phase(&PhaseGate::NoPhase);
            self.apply_levels()?;
            self.scheduler.start()?;
            self.started = true;
        }
        let update = match lockstep {
            Some(t_ns) => self.link.poll_lockstep(t_ns, LOCKSTEP_TIMEOUT)?,
            None => self.link.poll(now_s),
        };
        // Back from a link loss: re-enter offboard only while qosrt holds control (not in
        // observe mode, not after a takeover, not during the landing it ordered).
        if self.sequencer.status().holds_control
            && self.link.failsafe_action() == FailsafeAction::HoldThenReenter
        {
            self.link.recover()?;
        }
        self.take_telemetry(now, &update)?;
        self.take_frames(now_s);
        self.scheduler.run_until(now)?;

        let landing = self
            .setpoints
            .latest()
            .filter(|m| now_s - m.stamp.as_secs_f64() <= SETPOINT_MAX_AGE_S)
            .map(|m| m.value);
        // Every change of the landing's state is an event: how a landing went, or why not.
        if let Some(mode) = landing.map(|l| l.mode) {
            if self.last_landing_mode != Some(mode) {
                self.last_landing_mode = Some(mode);
                let event = format!("landing: {mode:?}");
                tracing::info!(time_s = now_s, "{event}");
                self.note(now_s, event);
            }
        }
        let telemetry = self.link.telemetry();
        let view = match (telemetry.autopilot(), telemetry.position_ned_m()) {
            (Some(status), Some(position_ned_m)) => Some(AutopilotView {
                kind: status.kind,
                armed: status.armed,
                mode: status.mode,
                landed: telemetry.vehicle_state(now_s).is_some_and(|s| s.landed),
                position_ned_m,
            }),
            _ => None,
        };
        let (mut commands, events) = self.sequencer.step(&SequencerInput {
            time_s: now_s,
            link_up: update.status == LinkStatus::Connected,
            autopilot: view,
            landing,
            land_now: self.land_now,
        });
        self.after_sequencer(now, &events)?;
        if self.options.landing_target {
            commands.extend(self.landing_target(now_s));
        }
        commands.extend(self.stream_requests(now_s));
        // A velocity setpoint carries the capture of the frame whose fix it answers.
        let answered_capture_s = self.relative.peek().and_then(|m| m.value.last_fix_time_s);
        for command in &commands {
            if let VehicleCommand::VelocityNed {
                velocity_ned_m_s, ..
            } = command
            {
                for observer in &self.observers {
                    observer.velocity_setpoint(now_s, velocity_ned_m_s);
                }
            }
            match (command, answered_capture_s) {
                (VehicleCommand::VelocityNed { .. }, Some(capture_s)) => {
                    self.link.send_stamped(command, capture_s)?
                }
                _ => self.link.send(command)?,
            };
        }
        self.note_vision_latency(now_s, &commands);
        if let Some(t_ns) = lockstep {
            self.link.end_tick(t_ns)?;
        }
        self.take_plan_requests(now_s)?;
        self.record_step(now_s, lockstep);
        self.observe_tasks(now_s);
        self.log
            .loop_step
            .record(started.elapsed().as_nanos() as u64);
        Ok(StepReport {
            link: update.status,
            commands,
            events,
            landing,
        })
    }

    /// Ends the mission early (time up, Ctrl-C): lands the vehicle where it is if qosrt holds
    /// control. The caller keeps stepping until [`MissionStatus::finished`].
    pub fn request_landing(&mut self, now_s: f64, reason: &str) -> Result<(), RunnerError> {
        let (commands, events) = self.sequencer.request_landing(reason);
        for event in &events {
            self.note(now_s, describe_mission(event));
        }
        for command in &commands {
            self.link.send(command)?;
        }
        self.note_vision_latency(now_s, &commands);
        Ok(())
    }

    /// Unparks `thread` when a frame arrives or the landing task publishes a setpoint: a loop
    /// that sleeps between steps wakes to take the frame, or to send the setpoint, at once.
    pub fn wake_on_input(&mut self, thread: std::thread::Thread) -> Result<(), RunnerError> {
        if let Some(camera) = self.camera.as_mut() {
            camera.wake_on_frame(thread.clone());
        }
        self.scheduler
            .bus()
            .activity(LANDING_SETPOINT.name())?
            .watch(thread);
        Ok(())
    }

    /// Stops the tasks; statistics stay readable.
    pub fn stop(&mut self) {
        self.scheduler.stop();
    }

    pub fn status(&self) -> MissionStatus {
        self.sequencer.status()
    }

    pub fn scheduler(&self) -> &S {
        &self.scheduler
    }

    /// The scheduler's id of config task `task` (an index into `config.tasks`); `None` for a
    /// task the scheduler does not hold.
    pub fn task_id(&self, task: usize) -> Option<TaskId> {
        self.task_ids.get(task).copied().flatten()
    }

    pub fn link(&self) -> &MavlinkLink {
        &self.link
    }

    pub fn governor(&self) -> &Governor {
        &self.governor
    }

    /// What the camera source counted, while the runner has one.
    pub fn camera_stats(&self) -> Option<crate::camera::CameraStats> {
        self.camera
            .as_ref()
            .map(|camera| camera.stats())
            .or(self.ended_camera_stats)
    }

    pub fn log(&self) -> &MissionLog {
        &self.log
    }

    /// The companion computer's modelled power now: the phase's power model at the levels in
    /// force of the tasks that run in it; nothing before the first phase.
    pub fn companion_power_w(&self) -> f64 {
        let Some(phase) = self.phase else {
            return 0.0;
        };
        let levels = self.effective_levels(phase);
        self.governor
            .problem()
            .companion_power_w(phase, &levels)
            .unwrap_or(0.0)
    }

    fn take_telemetry(&mut self, now: Timestamp, update: &LinkUpdate) -> Result<(), RunnerError> {
        let now_s = now.as_secs_f64();
        if let Some(state) = update.vehicle_state {
            self.vehicle_topic.publish(now, state);
            for observer in &self.observers {
                observer.vehicle(now_s, &state);
            }
            self.vehicle_history.push(AttitudeSample {
                time_s: now_s,
                attitude: state.attitude,
                height_above_pad_m: state.height_above_pad_m,
                position_ned_m: state.position_ned_m,
                velocity_ned_m_s: state.velocity_ned_m_s,
                gimbal_attitude: state.gimbal_attitude,
            });
        }
        if let Some(status) = update.autopilot {
            self.log.autopilot(now_s, &status);
        }
        let Some(sample) = update.battery else {
            return Ok(());
        };
        self.log.battery(sample);
        for observer in &self.observers {
            observer.battery(&sample);
        }
        if let Some(recorder) = &self.recorder {
            recorder.battery(
                now_s,
                BatteryEstimate {
                    telemetry: sample,
                    companion_power_w: self.companion_power_w(),
                },
            );
        }
        self.reprice_at_measured_input_rates(now_s)?;
        let progress = self.progress_at(now_s);
        match self.governor.update(&sample, progress) {
            Ok(decisions) => self.take_decisions(now_s, decisions)?,
            Err(error) => {
                self.log.telemetry_refused += 1;
                self.note(now_s, format!("telemetry refused: {error}"));
            }
        }
        Ok(())
    }

    /// The governor's decisions: logged, recorded, told, and the levels put in force.
    fn take_decisions(
        &mut self,
        now_s: f64,
        decisions: Vec<GovernorEvent>,
    ) -> Result<(), RunnerError> {
        for event in decisions {
            if let GovernorEvent::LandNow(_) = &event {
                self.land_now = Some("the battery cannot reach the end of the mission");
            }
            let description = event.describe(&self.model.config.tasks);
            tracing::info!(time_s = now_s, "governor: {description}");
            let decision =
                GovernorDecision::from_event(now_s, &event, &self.model.config.tasks, description);
            if let Some(recorder) = &self.recorder {
                recorder.governor(decision.clone());
            }
            for observer in &self.observers {
                observer.governor(&decision);
            }
            self.log.governor(decision);
        }
        self.apply_levels()
    }

    /// The governor prices triggered tasks at the rates their inputs were measured at, once
    /// those moved (a camera slower than declared, a detector that stopped finding the pad).
    fn reprice_at_measured_input_rates(&mut self, now_s: f64) -> Result<(), RunnerError> {
        let counts = self.input_activity.iter().map(|a| a.published()).collect();
        let Some(rates) = self.input_rates.sample(now_s, counts) else {
            return Ok(());
        };
        let described: Vec<String> = rates
            .iter()
            .map(|(topic, rate)| format!("{topic} {rate:.2}/s"))
            .collect();
        tracing::info!(
            time_s = now_s,
            "input rates measured: {}",
            described.join(", ")
        );
        self.governor
            .reprice(self.model.plan_problem_at(&rates))
            .map_err(RunnerError::Governor)
    }

    /// The rates the governor prices triggered tasks at: declared, then measured.
    pub fn input_rates(&self) -> &crate::energy::InputRates {
        self.input_rates.in_force()
    }

    /// Phase changes: the scheduler runs the new phase's tasks, the plugins hear of it, the
    /// levels follow the plan for it.
    fn after_sequencer(
        &mut self,
        now: Timestamp,
        events: &[MissionEvent],
    ) -> Result<(), RunnerError> {
        let now_s = now.as_secs_f64();
        for event in events {
            let line = describe_mission(event);
            tracing::info!(time_s = now_s, "mission: {line}");
            self.note(now_s, line);
        }
        let status = self.sequencer.status();
        let phase = if status.finished { None } else { status.phase };
        if phase == self.phase {
            return Ok(());
        }
        self.phase = phase;
        let phase_name = phase.map(|index| self.model.config.mission.phases[index].name.as_str());
        for observer in &self.observers {
            observer.phase(now.as_secs_f64(), phase_name);
        }
        // The sequencer's change reaches the tasks, the scheduler and the governor at once.
        match phase {
            Some(index) => {
                let name = self.model.config.mission.phases[index].name.clone();
                self.phase_topic.publish(
                    now,
                    MissionPhase {
                        index,
                        name: Arc::from(name.as_str()),
                        landing: self.sequencer.plan().kind(index) == Some(PhaseKind::Land),
                    },
                );
                self.scheduler.set_phase(&PhaseGate::Phase(name));
                self.governor
                    .enter_phase(index)
                    .map_err(RunnerError::Governor)?;
            }
            None => self.scheduler.set_phase(&PhaseGate::NoPhase),
        }
        self.apply_levels()
    }

    /// MAV_CMD_SET_MESSAGE_INTERVAL for every stream the loop needs, once the autopilot is heard.
    fn stream_requests(&mut self, now_s: f64) -> Vec<VehicleCommand> {
        let (sent, last_s) = self.stream_requests;
        let heard = self.link.telemetry().autopilot().is_some();
        if !heard || sent >= STREAM_REQUESTS || now_s - last_s < STREAM_REQUEST_PERIOD_S {
            return Vec::new();
        }
        self.stream_requests = (sent + 1, now_s);
        TELEMETRY_STREAMS
            .iter()
            .map(
                |&(message_id, rate_hz)| VehicleCommand::SetMessageInterval {
                    message_id,
                    interval_us: (1e6 / rate_hz).round() as i64,
                },
            )
            .collect()
    }

    /// The governor's levels for `phase` with the fixed ones put in.
    fn effective_levels(&self, phase: usize) -> Vec<TaskLevel> {
        self.with_fixed(self.governor.phase_levels(phase).unwrap_or_default())
    }

    /// `levels` with every `--fix` task at its fixed level (added when missing).
    fn with_fixed(&self, levels: &[TaskLevel]) -> Vec<TaskLevel> {
        let mut levels = levels.to_vec();
        for &(task, level) in &self.fixed {
            match levels.iter_mut().find(|l| l.task == task) {
                Some(entry) => entry.level = level,
                None => levels.push(TaskLevel { task, level }),
            }
        }
        levels
    }

    /// Sets every scheduled task to the level in force: fixed, else the governor's.
    fn apply_levels(&mut self) -> Result<(), RunnerError> {
        for wanted in self.with_fixed(self.governor.current_levels()) {
            let Some(id) = self.task_ids[wanted.task] else {
                continue;
            };
            if let Some(current) = self.scheduler.level(id) {
                if current != wanted.level {
                    self.scheduler.set_level(id, wanted.level)?;
                }
            }
        }
        Ok(())
    }
}

/// `(task index, level index)` for every `--fix TASK=VALUE`.
fn resolve_fixed_levels(
    model: &MissionModel,
    fixed: &[(String, f64)],
) -> Result<Vec<(usize, usize)>, RunnerError> {
    fixed
        .iter()
        .map(|(name, value)| {
            let error = |why: String| RunnerError::FixedLevel {
                task: name.clone(),
                value: *value,
                why,
            };
            let tasks = &model.config.tasks;
            let task = tasks.iter().position(|t| &t.name == name).ok_or_else(|| {
                let known: Vec<&str> = tasks.iter().map(|t| t.name.as_str()).collect();
                error(format!("no such task; the tasks are {}", known.join(", ")))
            })?;
            let levels = &tasks[task].levels;
            let level = levels
                .iter()
                .position(|v| (v - value).abs() <= 1e-9 * v.abs().max(1.0))
                .ok_or_else(|| error(format!("not one of the task's levels {levels:?}")))?;
            Ok((task, level))
        })
        .collect()
}

/// A mission event in one line.
pub fn describe_mission(event: &MissionEvent) -> String {
    match event {
        MissionEvent::Armed => "armed".into(),
        MissionEvent::TookOff => "took off".into(),
        MissionEvent::OffboardEngaged => "offboard engaged".into(),
        MissionEvent::PhaseStarted { name, .. } => format!("phase {name} started"),
        MissionEvent::LinkLost => "MAVLink link lost: failsafe (autopilot holds)".into(),
        MissionEvent::LinkRestored => "MAVLink link restored".into(),
        MissionEvent::LandNow { reason } => format!("land now: {reason}"),
        MissionEvent::Touchdown => "touchdown".into(),
        MissionEvent::Aborted { reason } => format!("mission aborted: {reason}"),
        MissionEvent::TakenOver { mode } => {
            format!("control taken over (mode {mode:?}): qosrt stopped commanding")
        }
        MissionEvent::LandingHere { reason } => format!("landing where the vehicle is: {reason}"),
        MissionEvent::Disarmed => "landed and disarmed".into(),
    }
}
