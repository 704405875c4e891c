//! Scoring the hazard CNN as the seed did: a hazard counts as seen when some detection of its
//! class was placed within [`MATCH_RADIUS_M`] of its true position on the ground. Pure
//! bookkeeping; the mission loop feeds it the reports.

use runtime::topics::HazardReport;
use sim::scene::{Hazard, HazardClass};
use std::collections::BTreeSet;

/// The seed's criterion: within 2 m of the true position.
pub const MATCH_RADIUS_M: f64 = 2.0;

/// The tally over one flight.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct HazardScore {
    seen: BTreeSet<u32>,
    /// Frames the CNN processed.
    pub frames: usize,
    /// Detections placed on the ground.
    pub detections: usize,
    /// Detections with no hazard of their class within the radius (false alarms and
    /// misclassifications).
    pub false_detections: usize,
    /// Detections that could not be placed (no vehicle position, a pixel above the horizon).
    pub unplaced: usize,
}

impl HazardScore {
    /// Books one frame's report.
    pub fn add(&mut self, hazards: &[Hazard], report: &HazardReport) {
        self.frames += 1;
        for detection in &report.detections {
            let Some(position) = detection.position_ned_m else {
                self.unplaced += 1;
                continue;
            };
            self.detections += 1;
            let class = detection.class_name.parse::<HazardClass>().ok();
            let hit = hazards
                .iter()
                .filter(|h| Some(h.class) == class)
                .map(|h| ((h.north_m - position.x).hypot(h.east_m - position.y), h.id))
                .filter(|&(distance_m, _)| distance_m <= MATCH_RADIUS_M)
                .min_by(|a, b| a.0.total_cmp(&b.0));
            match hit {
                Some((_, id)) => {
                    self.seen.insert(id);
                }
                None => self.false_detections += 1,
            }
        }
    }

    /// How many distinct hazards were seen.
    pub fn seen(&self) -> usize {
        self.seen.len()
    }

    pub fn seen_ids(&self) -> impl Iterator<Item = u32> + '_ {
        self.seen.iter().copied()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::vision::yolo::PixelBox;
    use nalgebra::Vector3;
    use runtime::topics::HazardDetection;
    use std::sync::Arc;

    fn hazard(id: u32, class: HazardClass, north_m: f64, east_m: f64) -> Hazard {
        Hazard {
            class,
            north_m,
            east_m,
            yaw_rad: 0.0,
            id,
        }
    }

    fn detection(class: &str, position: Option<[f64; 2]>) -> HazardDetection {
        HazardDetection {
            class_id: 0,
            class_name: Arc::from(class),
            confidence: 0.9,
            bbox: PixelBox::from_centre(0.0, 0.0, 1.0, 1.0),
            position_ned_m: position.map(|[n, e]| Vector3::new(n, e, 0.0)),
        }
    }

    fn report(detections: Vec<HazardDetection>) -> HazardReport {
        HazardReport {
            frame_index: 0,
            capture_time_s: 0.0,
            detections,
            backend: "test",
            inference_ms: 0.0,
        }
    }

    #[test]
    fn a_hazard_is_seen_by_a_detection_of_its_class_within_two_metres() {
        let hazards = [
            hazard(0, HazardClass::Person, 10.0, 0.0),
            hazard(1, HazardClass::Animal, 10.0, 3.0),
            hazard(2, HazardClass::Vehicle, 50.0, 0.0),
        ];
        let mut score = HazardScore::default();
        score.add(
            &hazards,
            &report(vec![
                // 1.9 m from the person: seen.
                detection("person", Some([11.9, 0.0])),
                // Near the animal but called a person, and 2.2 m from the person: a false alarm.
                detection("person", Some([10.0, 2.2])),
                // 2.1 m from the vehicle: too far.
                detection("vehicle", Some([52.1, 0.0])),
                // An unknown class never matches.
                detection("tractor", Some([10.0, 3.0])),
                detection("animal", None),
            ]),
        );
        score.add(
            &hazards,
            &report(vec![detection("person", Some([10.5, 0.5]))]),
        );
        assert_eq!(score.seen(), 1);
        assert_eq!(score.seen_ids().collect::<Vec<_>>(), vec![0]);
        assert_eq!(score.frames, 2);
        assert_eq!(score.detections, 5);
        assert_eq!(score.false_detections, 3);
        assert_eq!(score.unplaced, 1);
        // Of two same-class hazards within reach, the nearer is credited.
        let pair = [
            hazard(0, HazardClass::Animal, 0.0, 0.0),
            hazard(1, HazardClass::Animal, 0.0, 3.0),
        ];
        let mut score = HazardScore::default();
        score.add(&pair, &report(vec![detection("animal", Some([0.0, 1.8]))]));
        assert_eq!(score.seen_ids().collect::<Vec<_>>(), vec![1]);
    }
}
