//! One task's instance and bookkeeping: start, step, failure, restart, stats.

use super::cadence::{Cadence, Completion};
use super::stats::StatsAccum;
use super::timing::SplitMix64;
use super::trigger::InputTrigger;
use super::*;
use crate::task::{panic_as_failure, TaskError};

/// What a build hands to an execution mode.
pub(crate) struct Parts {
    pub runners: Vec<TaskRunner>,
    pub bus: Bus,
    pub resources: Resources,
    pub health: MissionHealth,
}

/// What happened in one activation.
#[derive(Debug, Default)]
pub(crate) struct ActivationReport {
    /// A fresh instance was built (and started) before the step.
    pub restarted: bool,
    /// `step` was called.
    pub stepped: bool,
    pub failure: Option<Failure>,
    /// The step's own cost report (virtual time).
    pub reported_cost: Option<Duration>,
    /// Input-triggered: the inputs superseded before this run took the newest.
    pub dropped_inputs: u64,
}

#[derive(Debug, Clone)]
pub(crate) struct Failure {
    pub message: String,
    pub gave_up: bool,
}

pub(crate) fn lock<T>(mutex: &Mutex<T>) -> MutexGuard<'_, T> {
    // Stats and worker state stay consistent under a panic (no step runs under these locks).
    mutex.lock().unwrap_or_else(PoisonError::into_inner)
}

/// One task's instance and bookkeeping; owned by the virtual loop or by the task's worker thread.
pub(crate) struct TaskRunner {
    pub(super) index: usize,
    pub(super) config: TaskConfig,
    /// `[task.params]` without the scheduler's keys.
    pub(super) params: toml::Table,
    pub(super) factory: TaskFactory,
    pub(super) instance: Option<Box<dyn Task>>,
    pub(super) levels: Vec<QosLevel>,
    pub(super) level: usize,
    pub(super) cadence: Cadence,
    /// Set for an input-triggered task: it runs on its input, the cadence's period its cap.
    pub(super) trigger: Option<InputTrigger>,
    pub(super) restart: RestartPolicy,
    pub(super) restarts: u32,
    pub(super) timing: Option<TimingModel>,
    pub(super) rng: SplitMix64,
    pub(super) seed: u64,
    pub(super) activations: u64,
    pub(super) state: TaskHealth,
    pub(super) stats: Arc<Mutex<StatsAccum>>,
    pub(super) health: MissionHealth,
    pub(super) bus: Bus,
    pub(super) lease: Option<ResourceLease>,
    /// Runs in the current mission phase; a suspended task is never activated.
    pub(super) active: bool,
}

impl TaskRunner {
    pub fn name(&self) -> &str {
        &self.config.name
    }

    pub fn config(&self) -> &TaskConfig {
        &self.config
    }

    pub fn level(&self) -> usize {
        self.level
    }

    pub fn level_count(&self) -> usize {
        self.levels.len()
    }

    pub fn stats_handle(&self) -> Arc<Mutex<StatsAccum>> {
        self.stats.clone()
    }

    /// Runs in the mission's current phase.
    pub fn is_active(&self) -> bool {
        self.active
    }

    /// Still activated: not failed for good, and not suspended outside its phases.
    pub fn is_scheduled(&self) -> bool {
        self.state != TaskHealth::Failed && self.active
    }

    /// Applies a phase gate at `now`: a task the gate no longer admits is suspended (its
    /// instance kept, never stepped); one it admits again resumes with an activation at `now`.
    /// Returns the change, if any.
    pub fn apply_gate(&mut self, gate: &PhaseGate, now: Timestamp) -> Option<bool> {
        self.set_active(gate.admits(&self.config), now)
    }

    /// Suspends or resumes the task at `now`; returns the change, if any.
    pub fn set_active(&mut self, active: bool, now: Timestamp) -> Option<bool> {
        if active == self.active {
            return None;
        }
        self.active = active;
        if active {
            self.restart_activations(now);
        }
        tracing::info!(task = %self.config.name, "task {}", if active { "resumed" } else { "suspended" });
        Some(active)
    }

    /// When the task is next due, seen at `now`: a periodic task on its grid; an input-triggered
    /// one for its pending input or its idle time, or `None` until an input arrives.
    pub fn next_due_at(&self, now: Timestamp) -> Option<Timestamp> {
        match &self.trigger {
            None => Some(self.cadence.next_ns()),
            Some(trigger) => trigger.next_due_ns(now.as_nanos(), self.cadence.period_ns()),
        }
        .map(Timestamp::from_nanos)
    }

    /// When the task would take an input that arrives at `now` (a periodic task: at its next
    /// activation).
    pub fn next_input_take(&self, now: Timestamp) -> Timestamp {
        match &self.trigger {
            None => Timestamp::from_nanos(self.cadence.next_ns()),
            Some(trigger) => Timestamp::from_nanos(
                trigger.earliest_input_run_ns(now.as_nanos(), self.cadence.period_ns()),
            ),
        }
    }

    /// An input-triggered task's input, if it has one.
    pub fn trigger(&self) -> Option<&InputTrigger> {
        self.trigger.as_ref()
    }

    /// Marks a new input as arrived at `now` (input-triggered tasks; no-op otherwise).
    pub fn notice_input(&mut self, now: Timestamp) {
        if let Some(trigger) = &mut self.trigger {
            trigger.notice(now.as_nanos());
        }
    }

    /// Activations begin afresh at `at`: a periodic task's first one is then, an
    /// input-triggered one waits for an input from then on.
    fn restart_activations(&mut self, at: Timestamp) {
        self.cadence = Cadence::new(at.as_nanos(), self.cadence.period_ns());
        if let Some(trigger) = &mut self.trigger {
            trigger.restart(at.as_nanos());
        }
    }

    /// Gives the instance its level and starts it; the first activation is at `first_activation`.
    pub fn start(&mut self, now: Timestamp, first_activation: Timestamp) -> Option<Failure> {
        self.restart_activations(first_activation);
        let mut instance = self.instance.take()?;
        let result = self.start_instance(instance.as_mut(), now);
        self.instance = Some(instance);
        match result {
            Ok(()) => {
                tracing::info!(task = %self.config.name, level = self.level, period_ms = self.levels[self.level].period_ms, "task started");
                None
            }
            Err(error) => Some(self.fail(&error)),
        }
    }

    /// Moves the first activation to `at` (real time: once every worker has started).
    pub fn reschedule_first(&mut self, at: Timestamp) {
        self.restart_activations(at);
    }

    /// `set_qos` then `start`, with panics caught.
    fn start_instance(&mut self, instance: &mut dyn Task, now: Timestamp) -> Result<(), TaskError> {
        let level = &self.levels[self.level];
        let mut ctx = TaskContext::new(&self.config.name, now, level, &self.health, self.seed)
            .with_activation(self.activations);
        let result = catch_unwind(AssertUnwindSafe(|| {
            instance.set_qos(level)?;
            instance.start(&mut ctx)
        }));
        panic_as_failure(result)
    }

    /// One activation, run at `now`: rebuild the instance if it failed before, then step.
    pub fn activate(&mut self, now: Timestamp) -> ActivationReport {
        let mut report = ActivationReport::default();
        if self.state == TaskHealth::Failed {
            return report;
        }
        // What the step will read has arrived by now; what comes during the step is next.
        if let Some(trigger) = &mut self.trigger {
            report.dropped_inputs = trigger.run(now.as_nanos(), self.cadence.period_ns());
        }
        if self.instance.is_none() {
            self.restarts += 1;
            lock(&self.stats).restarts += 1;
            report.restarted = true;
            let started: Result<_, Box<dyn std::error::Error>> =
                match self.factory.create(&self.params, &self.config, &self.bus) {
                    Ok(mut instance) => self
                        .start_instance(instance.as_mut(), now)
                        .map(|()| instance)
                        .map_err(Into::into),
                    Err(error) => Err(error.into()),
                };
            match started {
                Ok(instance) => {
                    self.instance = Some(instance);
                    self.set_state(TaskHealth::Running);
                    tracing::warn!(task = %self.config.name, restarts = self.restarts, "task restarted");
                }
                Err(error) => {
                    report.failure = Some(self.fail(error.as_ref()));
                    return report;
                }
            }
        }
        let Some(instance) = self.instance.as_mut() else {
            return report;
        };
        let mut ctx = TaskContext::new(
            &self.config.name,
            now,
            &self.levels[self.level],
            &self.health,
            self.seed,
        )
        .with_activation(self.activations);
        let result = catch_unwind(AssertUnwindSafe(|| instance.step(&mut ctx)));
        report.reported_cost = ctx.reported_step_cost();
        report.stepped = true;
        self.activations += 1;
        if let Err(error) = panic_as_failure(result) {
            report.failure = Some(self.fail(&error));
        }
        report
    }

    /// Virtual time's cost of the step just run: its own report, else the timing model, else 0.
    pub fn modelled_cost(&mut self, report: &ActivationReport) -> Duration {
        if !report.stepped {
            return Duration::ZERO;
        }
        report
            .reported_cost
            .or_else(|| {
                let level = self.level;
                let rng = &mut self.rng;
                self.timing.as_ref().map(|timing| timing.cost(level, rng))
            })
            .unwrap_or(Duration::ZERO)
    }

    /// Books the activation due at `due` whose work ran from `started` to `finished`, with the
    /// worker's bookkeeping time after the previous activation (real time).
    pub fn record(
        &mut self,
        due: Timestamp,
        started: Timestamp,
        finished: Timestamp,
        report: &ActivationReport,
        overhead_ns: Option<u64>,
    ) -> Completion {
        let completion = match &mut self.trigger {
            None => self
                .cadence
                .complete(due.as_nanos(), started.as_nanos(), finished.as_nanos()),
            Some(trigger) => {
                trigger.finish(finished.as_nanos());
                Completion {
                    overrun: finished.as_nanos().saturating_sub(started.as_nanos())
                        > self.cadence.period_ns(),
                    skipped: 0,
                }
            }
        };
        let mut stats = lock(&self.stats);
        stats.dropped_inputs += report.dropped_inputs;
        if report.stepped {
            stats.activations += 1;
            stats
                .step_time
                .record(finished.as_nanos().saturating_sub(started.as_nanos()));
            stats
                .lateness
                .record(started.as_nanos().saturating_sub(due.as_nanos()));
        }
        if completion.overrun && report.stepped {
            stats.overruns += 1;
        }
        stats.skipped += completion.skipped;
        if let Some(overhead_ns) = overhead_ns {
            stats.overhead.record(overhead_ns);
        }
        drop(stats);
        if completion.overrun && report.stepped {
            tracing::debug!(task = %self.config.name, step_ms = finished.saturating_duration_since(started).as_secs_f64() * 1e3, period_ms = self.levels[self.level].period_ms, "overrun");
        }
        completion
    }

    /// Switches to `level` at `now`: the next activation moves to `last + new period` (or now).
    /// The instance hears of it through `set_qos`; if that fails, the task fails.
    pub fn change_level(&mut self, level: usize, now: Timestamp) -> Option<Failure> {
        if level == self.level || level >= self.levels.len() {
            return None;
        }
        let from = self.level;
        self.level = level;
        let new_level = &self.levels[level];
        self.cadence
            .set_period(duration_to_nanos(new_level.period()), now.as_nanos());
        {
            let mut stats = lock(&self.stats);
            stats.level = level;
            stats.period_ms = new_level.period_ms;
        }
        tracing::info!(task = %self.config.name, from, to = level, knob = %new_level.knob, value = new_level.value, period_ms = new_level.period_ms, "QoS level changed");
        let instance = self.instance.as_mut()?;
        let result = catch_unwind(AssertUnwindSafe(|| instance.set_qos(new_level)));
        panic_as_failure(result)
            .err()
            .map(|error| self.fail(&error))
    }

    /// The instance failed: stop and drop it, then restart later or give up per the policy.
    /// The error is kept as text, in the stats and the failure report.
    fn fail(&mut self, error: &dyn std::error::Error) -> Failure {
        let message = error.to_string();
        {
            let mut stats = lock(&self.stats);
            stats.failures += 1;
            stats.last_error = Some(message.clone());
        }
        self.discard_instance();
        let gave_up = match self.restart {
            RestartPolicy::Never => true,
            RestartPolicy::OnFailure { max_restarts } => self.restarts >= max_restarts,
        };
        if gave_up {
            self.set_state(TaskHealth::Failed);
            // A task that is gone for good must not keep the GPU from a fallback.
            self.lease = None;
            tracing::error!(task = %self.config.name, error = %message, restarts = self.restarts, "task failed for good; the mission continues degraded");
        } else {
            self.set_state(TaskHealth::Restarting);
            tracing::error!(task = %self.config.name, error = %message, restarts = self.restarts, "task failed; restarting at its next activation");
        }
        Failure { message, gave_up }
    }

    fn discard_instance(&mut self) {
        if let Some(mut instance) = self.instance.take() {
            // A failed instance may be inconsistent: its stop and drop may panic too.
            let stopped = catch_unwind(AssertUnwindSafe(move || {
                instance.stop();
                drop(instance);
            }));
            if let Err(payload) = stopped {
                tracing::warn!(task = %self.config.name, error = %panic_message(payload.as_ref()), "task panicked while being stopped");
            }
        }
    }

    fn set_state(&mut self, state: TaskHealth) {
        self.state = state;
        self.health.set(self.index, state);
    }

    /// Drops an instance that was never started, without calling its `stop`.
    pub fn abandon(&mut self) {
        if let Some(instance) = self.instance.take() {
            if let Err(payload) = catch_unwind(AssertUnwindSafe(move || drop(instance))) {
                tracing::warn!(task = %self.config.name, error = %panic_message(payload.as_ref()), "task panicked while being dropped");
            }
        }
        self.lease = None;
    }

    /// Stops the instance for good (scheduler shutdown).
    pub fn shutdown(&mut self) {
        self.discard_instance();
        self.lease = None;
    }

    pub fn snapshot(&self) -> TaskStats {
        lock(&self.stats).snapshot(&self.config.name, self.state)
    }
}
