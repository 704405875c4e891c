//! Time for the runtime: a [`Clock`] trait with a monotonic [`WallClock`] for flight and a
//! deterministic [`VirtualClock`] that the simulator or the virtual-time scheduler advances.
//!
//! Both count [`Timestamp`]s in nanoseconds from the clock's own origin (its creation for the
//! wall clock, zero for the virtual clock), so a mission trace reads the same either way.

use std::fmt;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A point in time: nanoseconds since the clock's origin.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
pub struct Timestamp(u64);

impl Timestamp {
    pub const ZERO: Timestamp = Timestamp(0);

    pub const fn from_nanos(nanos: u64) -> Self {
        Timestamp(nanos)
    }

    pub const fn from_micros(micros: u64) -> Self {
        Timestamp(micros.saturating_mul(1_000))
    }

    pub const fn from_millis(millis: u64) -> Self {
        Timestamp(millis.saturating_mul(1_000_000))
    }

    /// Seconds from the origin; negative or non-finite input gives the origin, huge input
    /// saturates, so a bad number from a config can never panic.
    pub fn from_secs_f64(secs: f64) -> Self {
        if secs.is_nan() || secs <= 0.0 {
            return Timestamp::ZERO;
        }
        let nanos = secs * 1e9;
        if nanos >= u64::MAX as f64 {
            Timestamp(u64::MAX)
        } else {
            Timestamp(nanos.round() as u64)
        }
    }

    pub const fn as_nanos(self) -> u64 {
        self.0
    }

    pub fn as_secs_f64(self) -> f64 {
        self.0 as f64 * 1e-9
    }

    pub fn as_millis_f64(self) -> f64 {
        self.0 as f64 * 1e-6
    }

    /// Time since the origin as a [`Duration`].
    pub const fn since_origin(self) -> Duration {
        Duration::from_nanos(self.0)
    }

    pub fn saturating_add(self, duration: Duration) -> Self {
        Timestamp(self.0.saturating_add(duration_to_nanos(duration)))
    }

    /// `self − earlier`, or zero when `earlier` is later.
    pub fn saturating_duration_since(self, earlier: Timestamp) -> Duration {
        Duration::from_nanos(self.0.saturating_sub(earlier.0))
    }
}

impl fmt::Display for Timestamp {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}.{:09}s",
            self.0 / 1_000_000_000,
            self.0 % 1_000_000_000
        )
    }
}

/// A duration in nanoseconds, saturating at `u64::MAX` (585 years) instead of truncating.
pub(crate) fn duration_to_nanos(duration: Duration) -> u64 {
    u64::try_from(duration.as_nanos()).unwrap_or(u64::MAX)
}

/// A source of the current time. Shared between threads, so `Send + Sync`.
pub trait Clock: Send + Sync {
    fn now(&self) -> Timestamp;
}

/// The host's monotonic clock, for flight. Its origin is the moment it was created.
#[derive(Debug, Clone, Copy)]
pub struct WallClock {
    origin: Instant,
}

impl WallClock {
    pub fn new() -> Self {
        WallClock {
            origin: Instant::now(),
        }
    }

    /// The host instant at which this clock reads `at` (for sleeping until it).
    pub fn instant_at(&self, at: Timestamp) -> Instant {
        self.origin + at.since_origin()
    }
}

impl Default for WallClock {
    fn default() -> Self {
        Self::new()
    }
}

impl Clock for WallClock {
    fn now(&self) -> Timestamp {
        Timestamp(duration_to_nanos(self.origin.elapsed()))
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum ClockError {
    #[error("the virtual clock cannot go back from {now} to {requested}")]
    Backwards {
        now: Timestamp,
        requested: Timestamp,
    },
}

/// A clock that stands still until it is advanced: the simulator (or the virtual-time
/// scheduler) moves it, so a run depends only on its inputs, never on the host's speed.
///
/// Cloning gives another handle on the same clock.
#[derive(Debug, Clone, Default)]
pub struct VirtualClock {
    now_ns: Arc<AtomicU64>,
}

impl VirtualClock {
    /// A clock at the origin.
    pub fn new() -> Self {
        Self::default()
    }

    /// Moves the clock to `to`; it never goes back (a trace must be monotonic).
    pub fn advance_to(&self, to: Timestamp) -> Result<(), ClockError> {
        // One advancer at a time is the intended use; the CAS keeps the clock monotonic even if
        // two advance concurrently.
        let mut current = self.now_ns.load(Ordering::Acquire);
        loop {
            if to.0 < current {
                return Err(ClockError::Backwards {
                    now: Timestamp(current),
                    requested: to,
                });
            }
            match self.now_ns.compare_exchange_weak(
                current,
                to.0,
                Ordering::AcqRel,
                Ordering::Acquire,
            ) {
                Ok(_) => return Ok(()),
                Err(actual) => current = actual,
            }
        }
    }

    /// Moves the clock forward by `by` (saturating).
    pub fn advance_by(&self, by: Duration) -> Timestamp {
        let by_ns = duration_to_nanos(by);
        let previous = self
            .now_ns
            .fetch_update(Ordering::AcqRel, Ordering::Acquire, |now| {
                Some(now.saturating_add(by_ns))
            })
            .unwrap_or_else(|now| now);
        Timestamp(previous.saturating_add(by_ns))
    }
}

impl Clock for VirtualClock {
    fn now(&self) -> Timestamp {
        Timestamp(self.now_ns.load(Ordering::Acquire))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn virtual_clock_moves_only_when_advanced_and_never_back() {
        let clock = VirtualClock::new();
        assert_eq!(clock.now(), Timestamp::ZERO);
        clock.advance_to(Timestamp::from_millis(20)).unwrap();
        let handle = clock.clone();
        assert_eq!(handle.now(), Timestamp::from_millis(20));
        assert_eq!(
            clock.advance_by(Duration::from_micros(5)),
            Timestamp::from_nanos(20_005_000)
        );
        assert_eq!(
            clock.advance_to(Timestamp::from_millis(1)),
            Err(ClockError::Backwards {
                now: Timestamp::from_nanos(20_005_000),
                requested: Timestamp::from_millis(1),
            })
        );
        assert_eq!(clock.now(), Timestamp::from_nanos(20_005_000));
        // Advancing to the same instant is allowed: several events share a time.
        clock.advance_to(clock.now()).unwrap();
    }

    #[test]
    fn wall_clock_is_monotonic_and_moves() {
        let clock = WallClock::new();
        let first = clock.now();
        std::thread::sleep(Duration::from_millis(2));
        let second = clock.now();
        assert!(second.saturating_duration_since(first) >= Duration::from_millis(2));
        assert!(clock.instant_at(second) <= Instant::now());
    }

    #[test]
    fn seconds_conversion_never_panics_on_bad_numbers() {
        assert_eq!(Timestamp::from_secs_f64(f64::NAN), Timestamp::ZERO);
        assert_eq!(Timestamp::from_secs_f64(-3.0), Timestamp::ZERO);
        assert_eq!(Timestamp::from_secs_f64(1e30).as_nanos(), u64::MAX);
        assert_eq!(Timestamp::from_secs_f64(1.5).as_nanos(), 1_500_000_000);
        assert_eq!(Timestamp::from_millis(1_234).to_string(), "1.234000000s");
    }
}
