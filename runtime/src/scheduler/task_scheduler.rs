//! The scheduler interface the mission runner drives, whichever clock.

use super::*;

/// What the mission runner needs of a scheduler, whichever clock drives it.
pub trait TaskScheduler {
    /// The scheduler's clock: what its tasks stamp their messages with.
    fn now(&self) -> Timestamp;
    fn bus(&self) -> &Bus;
    fn start(&mut self) -> Result<(), SchedulerError>;
    /// Virtual time: runs every activation due up to `now`. Real time: the workers run by
    /// themselves, so nothing.
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError>;
    /// The id of the task named `task`, if the scheduler holds it: the one place a task is
    /// looked up by name (a mission config may name tasks the scheduler was not given).
    fn task_id(&self, task: &str) -> Option<TaskId>;
    /// `task`'s QoS level; `None` for an id this scheduler did not give.
    fn level(&self, task: TaskId) -> Option<usize>;
    /// Changes `task`'s QoS level; [`SchedulerError::UnknownTaskId`] for an id this scheduler
    /// did not give.
    fn set_level(&mut self, task: TaskId, level: usize) -> Result<(), SchedulerError>;
    fn set_phase(&mut self, gate: &PhaseGate);
    /// When `task` next steps, where the scheduler knows ahead (virtual time).
    fn next_activation(&self, task: TaskId) -> Option<Timestamp>;
    fn stats(&self) -> Vec<TaskStats>;
    fn failed_tasks(&self) -> Vec<String>;
    fn stop(&mut self);
}

impl TaskScheduler for VirtualScheduler {
    fn now(&self) -> Timestamp {
        VirtualScheduler::now(self)
    }
    fn bus(&self) -> &Bus {
        VirtualScheduler::bus(self)
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        VirtualScheduler::start(self)
    }
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError> {
        VirtualScheduler::run_until(self, now).map(|_| ())
    }
    fn task_id(&self, task: &str) -> Option<TaskId> {
        VirtualScheduler::task_id(self, task)
    }
    fn level(&self, task: TaskId) -> Option<usize> {
        VirtualScheduler::level(self, task)
    }
    fn set_level(&mut self, task: TaskId, level: usize) -> Result<(), SchedulerError> {
        VirtualScheduler::set_level(self, task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        VirtualScheduler::set_phase(self, gate)
    }
    fn next_activation(&self, task: TaskId) -> Option<Timestamp> {
        VirtualScheduler::next_activation(self, task)
    }
    fn stats(&self) -> Vec<TaskStats> {
        VirtualScheduler::stats(self)
    }
    fn failed_tasks(&self) -> Vec<String> {
        VirtualScheduler::failed_tasks(self)
    }
    fn stop(&mut self) {
        VirtualScheduler::stop(self)
    }
}

impl TaskScheduler for RealTimeScheduler {
    fn now(&self) -> Timestamp {
        RealTimeScheduler::now(self)
    }
    fn bus(&self) -> &Bus {
        RealTimeScheduler::bus(self)
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        RealTimeScheduler::start(self)
    }
    fn run_until(&mut self, _now: Timestamp) -> Result<(), SchedulerError> {
        Ok(())
    }
    fn task_id(&self, task: &str) -> Option<TaskId> {
        RealTimeScheduler::task_id(self, task)
    }
    fn level(&self, task: TaskId) -> Option<usize> {
        RealTimeScheduler::level(self, task)
    }
    fn set_level(&mut self, task: TaskId, level: usize) -> Result<(), SchedulerError> {
        RealTimeScheduler::set_level(self, task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        RealTimeScheduler::set_phase(self, gate)
    }
    fn next_activation(&self, _task: TaskId) -> Option<Timestamp> {
        None
    }
    fn stats(&self) -> Vec<TaskStats> {
        RealTimeScheduler::stats(self)
    }
    fn failed_tasks(&self) -> Vec<String> {
        RealTimeScheduler::failed_tasks(self)
    }
    fn stop(&mut self) {
        RealTimeScheduler::stop(self)
    }
}

/// A scheduler chosen at run time (the simulator's harness flies in virtual or in real time).
impl TaskScheduler for Box<dyn TaskScheduler> {
    fn now(&self) -> Timestamp {
        (**self).now()
    }
    fn bus(&self) -> &Bus {
        (**self).bus()
    }
    fn start(&mut self) -> Result<(), SchedulerError> {
        (**self).start()
    }
    fn run_until(&mut self, now: Timestamp) -> Result<(), SchedulerError> {
        (**self).run_until(now)
    }
    fn task_id(&self, task: &str) -> Option<TaskId> {
        (**self).task_id(task)
    }
    fn level(&self, task: TaskId) -> Option<usize> {
        (**self).level(task)
    }
    fn set_level(&mut self, task: TaskId, level: usize) -> Result<(), SchedulerError> {
        (**self).set_level(task, level)
    }
    fn set_phase(&mut self, gate: &PhaseGate) {
        (**self).set_phase(gate)
    }
    fn next_activation(&self, task: TaskId) -> Option<Timestamp> {
        (**self).next_activation(task)
    }
    fn stats(&self) -> Vec<TaskStats> {
        (**self).stats()
    }
    fn failed_tasks(&self) -> Vec<String> {
        (**self).failed_tasks()
    }
    fn stop(&mut self) {
        (**self).stop()
    }
}
