//! When an input-triggered task runs, the activation logic both execution modes share.
//!
//! Semantics (`trigger = "input:TOPIC"` in the task's config):
//! - the task runs when a message arrives on its input, at once if it may: not while its
//!   previous step is still running, and not above its QoS level's rate, which is its **rate
//!   cap**. An arrival it may not take yet waits and is then taken with whatever came
//!   meanwhile: a latest-value input is read at its newest, and the messages it superseded are
//!   counted as dropped;
//! - the cap is a credit refilled at the level's rate, one period's worth spent by each run,
//!   holding two runs: over any stretch of time T the task runs at most T / period + 2 times,
//!   whatever its input does. Two, not one: a 10 fps detector on a 10 fps camera whose frames
//!   arrive 30–80 ms after capture takes each frame as it comes, where a strict one-period gap
//!   would hold every frame back to the latest arrival's phase (80 ms, measured);
//! - with `max_idle_ms` the task also runs on its own when it has not run for that long (a
//!   tracker predicting between fixes, guidance streaming while the camera is slow). An idle run
//!   waits for a full credit, so the input right after it still finds one and is answered at
//!   once;
//! - while suspended (outside its phases) it ignores its input; on resuming it waits for a new
//!   message (or its idle time).

use crate::bus::TopicActivity;
use std::sync::Arc;

/// Runs the rate credit holds.
const CREDIT_RUNS: u64 = 2;

#[derive(Debug)]
pub(crate) struct InputTrigger {
    activity: Arc<TopicActivity>,
    max_idle_ns: Option<u64>,
    /// The input's message count when the task last ran (or resumed).
    seen: u64,
    /// When the pending input was first noticed (the scheduler's clock).
    noticed_ns: Option<u64>,
    /// The rate credit, in nanoseconds of the level's period, at `credit_at_ns`; it grows with
    /// time up to the bucket's size (one or two periods).
    credit_ns: u64,
    credit_at_ns: u64,
    /// Due instant of the last run of either kind, or the start: the idle time counts from it.
    last_run_ns: u64,
    /// End of the last step: no run starts before.
    busy_until_ns: u64,
}

impl InputTrigger {
    pub fn new(activity: Arc<TopicActivity>, max_idle_ns: Option<u64>) -> Self {
        let seen = activity.published();
        InputTrigger {
            activity,
            max_idle_ns,
            seen,
            noticed_ns: None,
            credit_ns: u64::MAX,
            credit_at_ns: 0,
            last_run_ns: 0,
            busy_until_ns: 0,
        }
    }

    pub fn activity(&self) -> &Arc<TopicActivity> {
        &self.activity
    }

    /// Starts afresh at `now_ns` (start, resume): only messages from now on count.
    pub fn restart(&mut self, now_ns: u64) {
        self.seen = self.activity.published();
        self.noticed_ns = None;
        // A full credit: the first input is answered at once.
        self.credit_ns = u64::MAX;
        self.credit_at_ns = now_ns;
        self.last_run_ns = now_ns;
        self.busy_until_ns = now_ns;
    }

    fn credit_at(&self, at_ns: u64, period_ns: u64) -> u64 {
        self.credit_ns
            .saturating_add(at_ns.saturating_sub(self.credit_at_ns))
            .min(CREDIT_RUNS.saturating_mul(period_ns))
    }

    /// The first instant from `from_ns` at which the credit holds `need_ns`.
    fn credit_reaches(&self, need_ns: u64, from_ns: u64, period_ns: u64) -> u64 {
        let credit = self.credit_at(from_ns, period_ns);
        from_ns.saturating_add(need_ns.saturating_sub(credit))
    }

    /// A message the task has not run on yet is waiting.
    pub fn pending(&self) -> bool {
        self.activity.published() > self.seen
    }

    /// Marks a pending input as having arrived at `now_ns`, unless it was noticed before.
    pub fn notice(&mut self, now_ns: u64) {
        if self.pending() && self.noticed_ns.is_none() {
            self.noticed_ns = Some(now_ns);
        }
    }

    /// The earliest instant an input arriving now could run the task.
    pub fn earliest_input_run_ns(&self, now_ns: u64, period_ns: u64) -> u64 {
        self.credit_reaches(period_ns, now_ns, period_ns)
            .max(self.busy_until_ns)
    }

    /// When the task runs next, seen at `now_ns` with its level's `period_ns`: for the pending
    /// input, else on its idle time, else not until an input arrives (`None`).
    pub fn next_due_ns(&self, now_ns: u64, period_ns: u64) -> Option<u64> {
        if self.pending() {
            let arrived_ns = self.noticed_ns.unwrap_or(now_ns);
            return Some(self.earliest_input_run_ns(arrived_ns, period_ns));
        }
        let idle_ns = self.max_idle_ns?;
        let full_ns = CREDIT_RUNS.saturating_mul(period_ns);
        Some(
            self.last_run_ns
                .saturating_add(idle_ns)
                .max(self.credit_reaches(full_ns, self.last_run_ns, period_ns))
                .max(self.busy_until_ns),
        )
    }

    /// The task runs at `now_ns` with its level's `period_ns`; returns the inputs it dropped
    /// (superseded unread).
    pub fn run(&mut self, now_ns: u64, period_ns: u64) -> u64 {
        let published = self.activity.published();
        let dropped = published.saturating_sub(self.seen).saturating_sub(1);
        self.credit_ns = self.credit_at(now_ns, period_ns).saturating_sub(period_ns);
        self.credit_at_ns = now_ns;
        self.seen = published;
        self.noticed_ns = None;
        self.last_run_ns = now_ns;
        dropped
    }

    /// The step that began at the last run ended at `finished_ns`.
    pub fn finish(&mut self, finished_ns: u64) {
        self.busy_until_ns = finished_ns;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::{Bus, Topic};
    use crate::clock::Timestamp;

    const MS: u64 = 1_000_000;
    const FRAME: Topic<u32> = Topic::new("camera/frame", "u32");

    fn setup(max_idle_ns: Option<u64>) -> (InputTrigger, crate::bus::Publisher<u32>) {
        let bus = Bus::new();
        let publisher = bus.publisher(FRAME).unwrap();
        publisher.publish(Timestamp::ZERO, 0); // before the task: never counts
        let mut trigger = InputTrigger::new(bus.activity(FRAME.name()).unwrap(), max_idle_ns);
        trigger.restart(0);
        (trigger, publisher)
    }

    #[test]
    fn an_input_runs_the_task_when_it_arrives_and_never_before() {
        let (mut trigger, frames) = setup(None);
        assert!(!trigger.pending());
        assert_eq!(trigger.next_due_ns(5 * MS, 20 * MS), None);
        frames.publish(Timestamp::ZERO, 1);
        trigger.notice(7 * MS);
        // Seen later, still due at its arrival.
        assert_eq!(trigger.next_due_ns(9 * MS, 20 * MS), Some(7 * MS));
        assert_eq!(trigger.run(7 * MS, 20 * MS), 0);
        trigger.finish(8 * MS);
        assert_eq!(trigger.next_due_ns(8 * MS, 20 * MS), None);
    }

    #[test]
    fn the_level_caps_the_rate_and_superseded_inputs_count_as_dropped() {
        let (mut trigger, frames) = setup(None);
        // Two frames at once: the credit holds both.
        for at in [0, 10] {
            frames.publish(Timestamp::ZERO, 1);
            trigger.notice(at * MS);
            assert_eq!(trigger.next_due_ns(at * MS, 100 * MS), Some(at * MS));
            trigger.run(at * MS, 100 * MS);
            trigger.finish(at * MS + MS);
        }
        // Three frames before the credit holds a run again (10 ms left at 10 ms, 100 needed):
        // the task runs once, at 100 ms, on the newest.
        for (at, value) in [(30, 2), (60, 3), (90, 4)] {
            frames.publish(Timestamp::ZERO, value);
            trigger.notice(at * MS);
        }
        assert_eq!(trigger.next_due_ns(90 * MS, 100 * MS), Some(100 * MS));
        assert_eq!(trigger.run(100 * MS, 100 * MS), 2);
        // A step that outlasts the next arrival holds it until the step ends.
        trigger.finish(250 * MS);
        frames.publish(Timestamp::ZERO, 5);
        trigger.notice(210 * MS);
        // The credit is back (110 ms at 210 ms), the step is not done.
        assert_eq!(trigger.next_due_ns(210 * MS, 100 * MS), Some(250 * MS));
    }

    #[test]
    fn an_idle_task_runs_on_its_own_and_an_input_right_after_is_answered_at_once() {
        let (mut trigger, frames) = setup(Some(50 * MS));
        // Idle from the start: due one idle time after it.
        assert_eq!(trigger.next_due_ns(0, 20 * MS), Some(50 * MS));
        assert_eq!(trigger.run(50 * MS, 20 * MS), 0);
        trigger.finish(51 * MS);
        // An input 2 ms after the idle run: not held back by the 20 ms cap.
        frames.publish(Timestamp::ZERO, 1);
        trigger.notice(52 * MS);
        assert_eq!(trigger.next_due_ns(52 * MS, 20 * MS), Some(52 * MS));
        trigger.run(52 * MS, 20 * MS);
        trigger.finish(53 * MS);
        // Idle again 50 ms after that run: the credit (2 ms left, refilled at 1 per ms up to
        // two runs' 40 ms) is full again by then.
        assert_eq!(trigger.next_due_ns(53 * MS, 20 * MS), Some(102 * MS));
        // On an 80 ms level the idle run waits for the credit: 52 + 160 − 2 ms.
        assert_eq!(trigger.next_due_ns(53 * MS, 80 * MS), Some(210 * MS));
    }

    #[test]
    fn a_restart_forgets_what_came_before() {
        let (mut trigger, frames) = setup(None);
        frames.publish(Timestamp::ZERO, 1);
        trigger.notice(MS);
        trigger.restart(10 * MS);
        assert!(!trigger.pending());
        assert_eq!(trigger.next_due_ns(10 * MS, 20 * MS), None);
    }
}
