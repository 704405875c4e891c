//! [`ClockSync`]: the autopilot's clock as the companion sees it, from MAVLink TIMESYNC.
//!
//! The companion asks once a period (TIMESYNC { tc1: 0, ts1: its own time }); the autopilot
//! answers with tc1 = its time and ts1 echoed (PX4 and ArduPilot both do). If the two legs of
//! the round trip take equally long, the autopilot read its clock at the round trip's
//! midpoint: offset = tc1 − (ts1 + received) / 2, wrong by at most half the round trip. So the
//! estimate rests on the sample with the shortest round trip among the last [`WINDOW`] (NTP's
//! clock filter, RFC 5905 §10): one delayed exchange does not move it, and the window forgets
//! a sample within [`WINDOW`] periods as the two crystals drift apart (tens of ppm: well under
//! a millisecond over the window).
//!
//! A simulator's autopilot keeps simulated time, which may run at several times the wall
//! clock (ArduPilot's `--speedup`): the window's oldest and newest samples give the autopilot
//! clock's rate, taken as exactly 1 within [`RATE_TOLERANCE`] (crystals differ by ppm, so a
//! larger difference is a simulator), and the estimate runs at that rate from its sample. An
//! autopilot clock that goes back or leaps ahead of that rate by more than [`CLOCK_JUMP_NS`]
//! (a reboot, a clock set from GPS) starts the window again.
//!
//! Pure: the link sends the requests and hands over the replies with its clock.

use std::collections::VecDeque;

/// Samples the estimate chooses from.
pub const WINDOW: usize = 8;

/// Samples before the estimate is trusted.
pub const MIN_SAMPLES: usize = 3;

/// A reply slower than this says nothing useful about the offset (a congested radio).
pub const MAX_ROUND_TRIP_NS: i64 = 200_000_000;

/// A sample this far from the estimate is a clock that jumped, not noise.
pub const CLOCK_JUMP_NS: i64 = 1_000_000_000;

/// An autopilot clock rate this close to the companion's is the companion's (crystals).
pub const RATE_TOLERANCE: f64 = 0.01;

/// Requests waiting for a reply; older ones are forgotten (a reply that never came).
const MAX_PENDING: usize = 4;

/// One exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ClockSample {
    /// The autopilot's clock minus the companion's, in ns, at the round trip's midpoint.
    pub offset_ns: i64,
    pub round_trip_ns: i64,
    /// The round trip's midpoint on the companion's clock.
    pub midpoint_ns: i64,
}

impl ClockSample {
    /// The autopilot's clock at the midpoint.
    fn autopilot_ns(&self) -> i64 {
        self.midpoint_ns + self.offset_ns
    }
}

/// What the exchanges so far came to, for a report.
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct ClockSyncStats {
    pub requests: u64,
    pub replies: u64,
    /// Replies to no pending request, or too slow to use.
    pub replies_refused: u64,
    /// Times the autopilot's clock jumped and the estimate started again.
    pub clock_jumps: u64,
    /// The estimate (autopilot minus companion), once trusted (filled in by
    /// [`ClockSync::stats`]; the exchange keeps only the counts).
    pub offset_ns: Option<i64>,
    /// The round trip of the sample the estimate rests on.
    pub round_trip_ns: Option<i64>,
    /// That sample's round-trip midpoint on the companion's clock (offset plus midpoint is
    /// the autopilot's clock there).
    pub midpoint_ns: Option<i64>,
    /// Autopilot seconds per companion second (1 but for a simulator off the wall clock).
    pub rate: Option<f64>,
}

/// The TIMESYNC exchange's state.
#[derive(Debug, Clone)]
pub struct ClockSync {
    period_s: f64,
    last_request_s: Option<f64>,
    /// ts1 of the requests not answered yet, oldest first.
    pending_ns: VecDeque<i64>,
    samples: VecDeque<ClockSample>,
    stats: ClockSyncStats,
}

impl ClockSync {
    /// Asks every `period_s`.
    pub fn new(period_s: f64) -> Self {
        Self {
            period_s,
            last_request_s: None,
            pending_ns: VecDeque::new(),
            samples: VecDeque::new(),
            stats: ClockSyncStats::default(),
        }
    }

    /// ts1 of a request to send now, when one is due.
    pub fn request_if_due(&mut self, now_s: f64) -> Option<i64> {
        let due = self
            .last_request_s
            .is_none_or(|last| now_s - last >= self.period_s - 1e-9);
        if !due {
            return None;
        }
        self.last_request_s = Some(now_s);
        let ts1_ns = nanoseconds(now_s);
        if self.pending_ns.len() == MAX_PENDING {
            self.pending_ns.pop_front();
        }
        self.pending_ns.push_back(ts1_ns);
        self.stats.requests += 1;
        Some(ts1_ns)
    }

    /// Whether a request with this ts1 is waiting for its reply.
    pub fn is_pending(&self, ts1_ns: i64) -> bool {
        self.pending_ns.contains(&ts1_ns)
    }

    /// A reply (tc1, ts1) received at `now_s`; the sample it gave, if it was ours and usable.
    pub fn on_reply(&mut self, tc1_ns: i64, ts1_ns: i64, now_s: f64) -> Option<ClockSample> {
        let Some(index) = self.pending_ns.iter().position(|&t| t == ts1_ns) else {
            self.stats.replies_refused += 1;
            return None;
        };
        // Earlier requests will not be answered after this one.
        self.pending_ns.drain(..=index);
        let received_ns = nanoseconds(now_s);
        let round_trip_ns = received_ns - ts1_ns;
        if !(0..=MAX_ROUND_TRIP_NS).contains(&round_trip_ns) {
            self.stats.replies_refused += 1;
            return None;
        }
        self.stats.replies += 1;
        let midpoint_ns = ts1_ns + round_trip_ns / 2;
        let sample = ClockSample {
            offset_ns: tc1_ns - midpoint_ns,
            round_trip_ns,
            midpoint_ns,
        };
        if self.jumped_to(&sample) {
            self.samples.clear();
            self.stats.clock_jumps += 1;
        }
        if self.samples.len() == WINDOW {
            self.samples.pop_front();
        }
        self.samples.push_back(sample);
        Some(sample)
    }

    /// The sample the estimate rests on, once [`MIN_SAMPLES`] came.
    pub fn estimate(&self) -> Option<ClockSample> {
        (self.samples.len() >= MIN_SAMPLES)
            .then(|| self.best())
            .flatten()
    }

    /// `time_s` on the companion's clock as microseconds on the autopilot's.
    pub fn autopilot_time_us(&self, time_s: f64) -> Option<u64> {
        let estimate = self.estimate()?;
        let autopilot_ns = self.predict_ns(&estimate, nanoseconds(time_s));
        u64::try_from(autopilot_ns / 1000).ok()
    }

    /// The autopilot's clock rate against the companion's: from the window's oldest and
    /// newest samples, 1 within [`RATE_TOLERANCE`].
    fn rate(&self) -> f64 {
        let (Some(first), Some(last)) = (self.samples.front(), self.samples.back()) else {
            return 1.0;
        };
        let span_ns = last.midpoint_ns - first.midpoint_ns;
        if span_ns <= 0 {
            return 1.0;
        }
        let rate = (last.autopilot_ns() - first.autopilot_ns()) as f64 / span_ns as f64;
        if (rate - 1.0).abs() <= RATE_TOLERANCE {
            1.0
        } else {
            rate
        }
    }

    /// The autopilot's clock at `companion_ns`, running at the window's rate from `from`.
    fn predict_ns(&self, from: &ClockSample, companion_ns: i64) -> i64 {
        let elapsed_ns = (companion_ns - from.midpoint_ns) as f64;
        from.autopilot_ns() + (self.rate() * elapsed_ns).round() as i64
    }

    /// Whether the autopilot's clock went back, or ahead of its rate by a jump, since the
    /// newest sample.
    fn jumped_to(&self, sample: &ClockSample) -> bool {
        let Some(last) = self.samples.back() else {
            return false;
        };
        if sample.autopilot_ns() < last.autopilot_ns() {
            return true;
        }
        // With one sample there is no rate yet: only a step back is a jump.
        self.samples.len() >= 2
            && (sample.autopilot_ns() - self.predict_ns(last, sample.midpoint_ns)).abs()
                > CLOCK_JUMP_NS
    }

    /// The counts, and the estimate as it stands.
    pub fn stats(&self) -> ClockSyncStats {
        let trusted = self.estimate();
        ClockSyncStats {
            offset_ns: trusted.map(|s| s.offset_ns),
            round_trip_ns: trusted.map(|s| s.round_trip_ns),
            midpoint_ns: trusted.map(|s| s.midpoint_ns),
            rate: trusted.map(|_| self.rate()),
            ..self.stats
        }
    }

    /// The shortest round trip in the window (the earliest of equals).
    fn best(&self) -> Option<ClockSample> {
        self.samples.iter().copied().min_by_key(|s| s.round_trip_ns)
    }
}

fn nanoseconds(time_s: f64) -> i64 {
    (time_s * 1e9).round() as i64
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An autopilot whose clock runs `offset_s` ahead, answering after `out_s` and reaching
    /// the companion `back_s` later.
    fn exchange(
        sync: &mut ClockSync,
        sent_s: f64,
        offset_s: f64,
        out_s: f64,
        back_s: f64,
    ) -> Option<ClockSample> {
        let ts1 = sync.request_if_due(sent_s)?;
        let tc1 = ((sent_s + out_s + offset_s) * 1e9).round() as i64;
        sync.on_reply(tc1, ts1, sent_s + out_s + back_s)
    }

    #[test]
    fn the_offset_is_exact_when_the_legs_are_equal_and_the_shortest_trip_wins() {
        let mut sync = ClockSync::new(1.0);
        let offset_s = 1234.5678;
        // Slow, lopsided exchanges, then one quick symmetric one among them.
        let legs = [
            (0.040, 0.010),
            (0.030, 0.002),
            (0.0005, 0.0005),
            (0.050, 0.020),
        ];
        for (k, (out_s, back_s)) in legs.into_iter().enumerate() {
            let sample = exchange(&mut sync, 10.0 + k as f64, offset_s, out_s, back_s).unwrap();
            // Each sample is off by half the legs' difference, as the geometry says.
            let expected_error_s = (out_s - back_s) / 2.0;
            let error_s = sample.offset_ns as f64 * 1e-9 - offset_s;
            assert!((error_s - expected_error_s).abs() < 2e-9, "{sample:?}");
        }
        let estimate = sync.estimate().unwrap();
        assert_eq!(estimate.round_trip_ns, 1_000_000);
        assert!((estimate.offset_ns as f64 * 1e-9 - offset_s).abs() < 2e-9);
        // 20.0 s here is 1254.5678 s there.
        assert_eq!(sync.autopilot_time_us(20.0), Some(1_254_567_800));
        assert_eq!(sync.stats().replies, 4);
    }

    #[test]
    fn no_estimate_before_enough_samples_and_foreign_or_slow_replies_are_refused() {
        let mut sync = ClockSync::new(1.0);
        assert!(exchange(&mut sync, 0.0, 5.0, 0.001, 0.001).is_some());
        assert!(exchange(&mut sync, 1.0, 5.0, 0.001, 0.001).is_some());
        assert_eq!(sync.estimate(), None);
        assert_eq!(sync.autopilot_time_us(1.0), None);
        // Not due yet: no request, so nothing to answer.
        assert_eq!(sync.request_if_due(1.5), None);
        // A reply to someone else's request (another companion on the same autopilot).
        assert_eq!(sync.on_reply(7_000_000_000, 123, 1.6), None);
        // Answered too late to say anything.
        assert_eq!(exchange(&mut sync, 2.0, 5.0, 0.150, 0.150), None);
        assert_eq!(sync.stats().replies_refused, 2);
        assert!(exchange(&mut sync, 3.0, 5.0, 0.001, 0.001).is_some());
        assert!(sync.estimate().is_some());
    }

    #[test]
    fn a_jump_of_the_autopilots_clock_starts_the_estimate_again() {
        let mut sync = ClockSync::new(1.0);
        for k in 0..5 {
            exchange(&mut sync, k as f64, 100.0, 0.0002, 0.0002).unwrap();
        }
        // Rebooted: its clock is 99 s behind where it was, with slower replies after.
        exchange(&mut sync, 5.0, 1.0, 0.002, 0.002).unwrap();
        assert_eq!(sync.stats().clock_jumps, 1);
        assert_eq!(sync.estimate(), None);
        exchange(&mut sync, 6.0, 1.0, 0.002, 0.002).unwrap();
        exchange(&mut sync, 7.0, 1.0, 0.002, 0.002).unwrap();
        let estimate = sync.estimate().unwrap();
        assert!((estimate.offset_ns as f64 * 1e-9 - 1.0).abs() < 1e-6);
    }

    #[test]
    fn a_simulated_clock_at_five_times_the_wall_clock_is_followed_at_its_rate() {
        // ArduPilot's SITL at --speedup 5: 5 s of its time to each of ours, from 40 s.
        let mut sync = ClockSync::new(1.0);
        let there = |here_s: f64| 40.0 + 5.0 * here_s;
        for k in 0..5 {
            let sent_s = k as f64;
            let ts1 = sync.request_if_due(sent_s).unwrap();
            // It answers 0.5 ms after the request left; the answer takes 0.5 ms back.
            let tc1 = (there(sent_s + 0.0005) * 1e9).round() as i64;
            sync.on_reply(tc1, ts1, sent_s + 0.001).unwrap();
        }
        let stats = sync.stats();
        assert_eq!(stats.clock_jumps, 0, "{stats:?}");
        assert!((stats.rate.unwrap() - 5.0).abs() < 1e-6, "{stats:?}");
        let predicted_us = sync.autopilot_time_us(6.0).unwrap() as f64;
        assert!(
            (predicted_us - there(6.0) * 1e6).abs() < 1.0,
            "{predicted_us}"
        );
    }

    #[test]
    fn a_reply_that_never_came_does_not_block_the_next() {
        let mut sync = ClockSync::new(1.0);
        let lost = sync.request_if_due(0.0).unwrap();
        let ts1 = sync.request_if_due(1.0).unwrap();
        assert!(sync.is_pending(lost) && sync.is_pending(ts1));
        assert!(sync.on_reply(3_000_000_000, ts1, 1.001).is_some());
        // The lost one's late reply is not taken as fresh: it is refused.
        assert!(!sync.is_pending(lost));
        assert_eq!(sync.on_reply(3_000_000_000, lost, 1.002), None);
    }
}
