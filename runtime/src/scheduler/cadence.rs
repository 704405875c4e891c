//! The activation logic both execution modes share: when a task is due next, which activations
//! a long step made it miss, and how a period change moves the next activation.
//!
//! Semantics:
//! - activations fall on a grid `last + period`, anchored at the last activation (not at the
//!   end of the step), so a task keeps its phase and does not drift by its step time;
//! - an activation instant that falls while the task's previous step is still running (strictly
//!   before the step ends) is **skipped**: it never runs and is counted, and the task resumes on
//!   the next grid instant at or after the end of the step (no catch-up burst);
//! - a step that lasts longer than its period is an **overrun** (it always causes ≥ 1 skip);
//! - a period change re-anchors the grid: the next activation is `last + new_period`, or now if
//!   that is already past, so it takes effect within one new period.

/// When a task is next due, in nanoseconds on the scheduler's clock.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Cadence {
    period_ns: u64,
    next_ns: u64,
    last_activation_ns: Option<u64>,
}

/// What became of the activations after one step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct Completion {
    pub overrun: bool,
    pub skipped: u64,
}

impl Cadence {
    /// First activation at `start_ns`.
    pub fn new(start_ns: u64, period_ns: u64) -> Self {
        Cadence {
            // A zero period would make the loops spin; QosLevel guarantees ≥ 1 µs, this is belt.
            period_ns: period_ns.max(1),
            next_ns: start_ns,
            last_activation_ns: None,
        }
    }

    pub fn next_ns(&self) -> u64 {
        self.next_ns
    }

    pub fn period_ns(&self) -> u64 {
        self.period_ns
    }

    /// The activation due at `due_ns` ran a step from `started_ns` to `finished_ns`.
    pub fn complete(&mut self, due_ns: u64, started_ns: u64, finished_ns: u64) -> Completion {
        let period = self.period_ns;
        self.last_activation_ns = Some(due_ns);
        let mut next = due_ns.saturating_add(period);
        let mut skipped = 0;
        if finished_ns > next {
            // Grid instants strictly before the end of the step: ceil((finished − next) / period).
            skipped = (finished_ns - next).div_ceil(period);
            next = next.saturating_add(skipped.saturating_mul(period));
        }
        self.next_ns = next;
        Completion {
            overrun: finished_ns.saturating_sub(started_ns) > period,
            skipped,
        }
    }

    /// A new period from `now_ns` on. Before the first activation the start instant stands.
    pub fn set_period(&mut self, period_ns: u64, now_ns: u64) {
        self.period_ns = period_ns.max(1);
        if let Some(last) = self.last_activation_ns {
            self.next_ns = last.saturating_add(self.period_ns).max(now_ns);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    #[test]
    fn a_short_step_keeps_the_grid() {
        let mut cadence = Cadence::new(0, 10 * MS);
        assert_eq!(cadence.next_ns(), 0);
        // Started late and took 3 ms: the next activation is still on the 10 ms grid.
        let completion = cadence.complete(0, MS, 4 * MS);
        assert_eq!(completion, Completion::default());
        assert_eq!(cadence.next_ns(), 10 * MS);
    }

    #[test]
    fn a_long_step_overruns_and_skips_the_instants_it_covers() {
        let mut cadence = Cadence::new(0, 10 * MS);
        // 25 ms step: instants 10 and 20 fall inside it; 30 is next.
        let completion = cadence.complete(0, 0, 25 * MS);
        assert_eq!(
            completion,
            Completion {
                overrun: true,
                skipped: 2
            }
        );
        assert_eq!(cadence.next_ns(), 30 * MS);
        // Exactly one period: neither an overrun nor a skip; the next instant runs at once.
        let completion = cadence.complete(30 * MS, 30 * MS, 40 * MS);
        assert_eq!(completion, Completion::default());
        assert_eq!(cadence.next_ns(), 40 * MS);
        // Woken 12 ms late with a short step: the missed instant is skipped without an overrun.
        let completion = cadence.complete(40 * MS, 52 * MS, 53 * MS);
        assert_eq!(
            completion,
            Completion {
                overrun: false,
                skipped: 1
            }
        );
        assert_eq!(cadence.next_ns(), 60 * MS);
    }

    #[test]
    fn a_period_change_takes_effect_within_one_new_period() {
        let mut cadence = Cadence::new(0, 1000 * MS);
        cadence.complete(0, 0, MS);
        assert_eq!(cadence.next_ns(), 1000 * MS);
        // Faster at 300 ms: last + 20 ms is past, so the task runs now.
        cadence.set_period(20 * MS, 300 * MS);
        assert_eq!(cadence.next_ns(), 300 * MS);
        cadence.complete(300 * MS, 300 * MS, 301 * MS);
        assert_eq!(cadence.next_ns(), 320 * MS);
        // Faster again just after an activation: last + new period.
        cadence.set_period(5 * MS, 302 * MS);
        assert_eq!(cadence.next_ns(), 305 * MS);
        // Slower: the next activation moves out to last + the new period.
        cadence.set_period(100 * MS, 303 * MS);
        assert_eq!(cadence.next_ns(), 400 * MS);
    }

    #[test]
    fn before_the_first_activation_the_start_stands() {
        let mut cadence = Cadence::new(50 * MS, 10 * MS);
        cadence.set_period(500 * MS, 0);
        assert_eq!(cadence.next_ns(), 50 * MS);
        assert_eq!(cadence.period_ns(), 500 * MS);
    }
}
