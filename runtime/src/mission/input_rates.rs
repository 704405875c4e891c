//! [`InputRateMeter`]: how often the topics that trigger tasks actually deliver, so that the
//! governor prices a triggered task at the rate it runs at, not at its level.
//!
//! Pure: it is handed each topic's publish count with the time. A rate is the count's rise
//! over the last [`WINDOW_S`], counted from the topic's first message (a camera that has not
//! started yet is not a camera at 0 fps); the meter speaks of a topic only after a full window,
//! and only when its rate moved by more than [`CHANGE_FRACTION`] from the one in force (a
//! camera at 10 fps counts 99 to 101 frames in ten seconds: noise, not news).

use std::collections::VecDeque;

use crate::energy::InputRates;

/// The stretch a rate is measured over.
pub const WINDOW_S: f64 = 10.0;

/// A rate that moved less than this fraction is the rate in force.
pub const CHANGE_FRACTION: f64 = 0.1;

/// Publish counts of the trigger topics over the last window.
#[derive(Debug, Clone)]
pub struct InputRateMeter {
    topics: Vec<String>,
    /// Per topic, (time, count) since its first message, oldest first, spanning at least the
    /// window once full.
    samples: Vec<VecDeque<(f64, u64)>>,
    in_force: InputRates,
}

impl InputRateMeter {
    /// Meters `topics`, starting from the rates the plan was made with.
    pub fn new(topics: Vec<String>, in_force: InputRates) -> Self {
        Self {
            samples: vec![VecDeque::new(); topics.len()],
            topics,
            in_force,
        }
    }

    /// The rates the governor prices with now.
    pub fn in_force(&self) -> &InputRates {
        &self.in_force
    }

    /// Takes the counts (one per topic, in the order [`Self::new`] was given them) at `now_s`;
    /// the new rates when one moved, which are then in force.
    pub fn sample(&mut self, now_s: f64, counts: Vec<u64>) -> Option<InputRates> {
        debug_assert_eq!(counts.len(), self.topics.len());
        let mut moved = false;
        for ((topic, samples), count) in self.topics.iter().zip(&mut self.samples).zip(counts) {
            if count == 0 {
                continue;
            }
            samples.push_back((now_s, count));
            // Keep one sample at or before the window's start.
            while samples.len() > 2 && now_s - samples[1].0 >= WINDOW_S {
                samples.pop_front();
            }
            let (start_s, start_count) = samples[0];
            let span_s = now_s - start_s;
            if span_s < WINDOW_S {
                continue;
            }
            let rate = count.saturating_sub(start_count) as f64 / span_s;
            let news = self.in_force.get(topic).is_none_or(|&old| {
                (rate - old).abs() > CHANGE_FRACTION * old.max(f64::MIN_POSITIVE)
            });
            if news {
                self.in_force.insert(topic.clone(), rate);
                moved = true;
            }
        }
        moved.then(|| self.in_force.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn meter(declared: &[(&str, f64)]) -> InputRateMeter {
        InputRateMeter::new(
            vec!["camera/frame".into(), "vision/landing_marker".into()],
            declared.iter().map(|(t, r)| (t.to_string(), *r)).collect(),
        )
    }

    /// Counts at 2 Hz sampling of a 10 fps camera and a detector at `fix_hz`.
    fn feed(
        meter: &mut InputRateMeter,
        from_s: f64,
        to_s: f64,
        camera_hz: f64,
        fix_hz: f64,
    ) -> Vec<(f64, InputRates)> {
        let mut changes = Vec::new();
        let mut t = from_s;
        while t <= to_s + 1e-9 {
            let counts = vec![(t * camera_hz).floor() as u64, (t * fix_hz).floor() as u64];
            if let Some(rates) = meter.sample(t, counts) {
                changes.push((t, rates));
            }
            t += 0.5;
        }
        changes
    }

    #[test]
    fn a_rate_is_news_once_a_window_has_passed_and_only_when_it_moved() {
        let mut meter = meter(&[("camera/frame", 10.0)]);
        let changes = feed(&mut meter, 0.0, 30.0, 10.0, 5.0);
        // After the first full window: the detector's topic had no rate, so that is news;
        // the camera's 10 fps is the declared one.
        assert_eq!(changes.len(), 1, "{changes:?}");
        let (at_s, rates) = &changes[0];
        // Counted from the first sample that saw a message, at 0.5 s.
        assert_eq!(*at_s, 0.5 + WINDOW_S);
        assert!((rates["camera/frame"] - 10.0).abs() < 0.11);
        assert!((rates["vision/landing_marker"] - 5.0).abs() < 0.11);
    }

    #[test]
    fn a_camera_that_slows_down_is_measured_within_a_window() {
        let mut meter = meter(&[("camera/frame", 10.0), ("vision/landing_marker", 5.0)]);
        assert!(feed(&mut meter, 0.0, 20.0, 10.0, 5.0).is_empty());
        // From 20 s the camera gives 4 fps (counts carry on from where they were).
        let mut changes = Vec::new();
        let mut t: f64 = 20.5;
        while t <= 40.0 {
            let camera = 200 + ((t - 20.0) * 4.0).floor() as u64;
            let fixes = (t * 5.0).floor() as u64;
            if let Some(rates) = meter.sample(t, vec![camera, fixes]) {
                changes.push((t, rates));
            }
            t += 0.5;
        }
        // It is news once the window's rate is more than 10 % under 10 fps (two seconds at
        // 4 fps: 8.8 fps over the window), again each time it moves 10 % more, and last when
        // the whole window is at 4 fps.
        let first = &changes[0];
        assert_eq!(first.0, 22.0, "{changes:?}");
        assert!((first.1["camera/frame"] - 8.8).abs() < 1e-9, "{changes:?}");
        assert_eq!(changes.last().unwrap().0, 30.0, "{changes:?}");
        let last = changes.last().unwrap();
        assert!((last.1["camera/frame"] - 4.0).abs() < 0.11, "{changes:?}");
        assert_eq!(meter.in_force()["camera/frame"], last.1["camera/frame"]);
    }

    #[test]
    fn a_topic_that_falls_silent_is_measured_at_zero_one_never_heard_is_not_measured() {
        let mut meter = meter(&[("camera/frame", 10.0)]);
        let mut last = None;
        for k in 0..=80 {
            let t = k as f64 * 0.5;
            // The camera gives 40 frames in its first 4 s, then nothing; the detector never
            // publishes.
            let camera = (t.min(4.0) * 10.0) as u64;
            if let Some(rates) = meter.sample(t, vec![camera, 0]) {
                last = Some(rates);
            }
        }
        let rates = last.expect("silence is news");
        assert_eq!(rates["camera/frame"], 0.0);
        assert!(!rates.contains_key("vision/landing_marker"), "{rates:?}");
    }
}
