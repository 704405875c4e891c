//! What a simulated mission reports, and the summary over many seeds. Pure data and
//! statistics; the harness's loop and its scoring fill it.

use serde::Serialize;

/// One QoS change the governor made, or a land-now, with its reason.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct QosChange {
    pub time_s: f64,
    pub description: String,
}

/// A sample of the trajectories and the battery, for the SVG.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct TrackSample {
    pub time_s: f64,
    pub vehicle_ne_m: [f64; 2],
    pub altitude_m: f64,
    pub tractor_ne_m: [f64; 2],
    pub battery_soc: f64,
}

/// The QoS level every task ran at from `time_s` on (task, level index, knob value), for the
/// SVG of levels over time.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct QosSample {
    pub time_s: f64,
    pub levels: Vec<(String, usize, f64)>,
}

/// How one simulated mission went.
#[derive(Debug, Clone, PartialEq, Default, Serialize)]
pub struct SimOutcome {
    pub seed: u64,
    /// Touched down on the pad.
    pub landed_on_pad: bool,
    /// Touched down somewhere (pad or ground).
    pub touched_down: bool,
    /// Horizontal distance of the vehicle's centre from the pad's centre at touchdown.
    pub touchdown_error_m: Option<f64>,
    /// The vehicle's tilt from the vertical at touchdown, degrees.
    pub touchdown_tilt_deg: Option<f64>,
    /// Down-positive speed at the touchdown: above about 1 m/s a landing is hard.
    pub touchdown_vertical_speed_m_s: Option<f64>,
    /// From the start of the landing phase to touchdown.
    pub time_to_land_s: Option<f64>,
    /// How long the tracker had gone without a vision fix when the vehicle touched down (the
    /// fix's age at the runtime's last step before contact): the blind end of the descent,
    /// flown on the tracker's prediction. `None` without a touchdown or a fix.
    pub blind_before_contact_s: Option<f64>,
    /// From arming to the end of the simulation.
    pub mission_time_s: f64,
    pub flight_energy_wh: f64,
    pub companion_energy_wh: f64,
    pub battery_left_fraction: f64,
    /// The landing procedure went back to searching this many times (a lost target).
    pub landing_aborts: u32,
    pub qos_changes: Vec<QosChange>,
    /// Mission events (phases, link loss, failsafe...) with their times.
    pub events: Vec<(f64, String)>,
    /// Hazards reported within 2 m and correctly classified, and how many were on the path.
    /// `None` when no hazard detector ran.
    pub hazards_seen: Option<usize>,
    pub hazards_total: usize,
    /// Frames the hazard CNN processed.
    pub hazard_frames: usize,
    /// Hazard detections with no hazard of their class within 2 m.
    pub hazard_false_detections: usize,
    /// The inference backend the hazard CNN ran on.
    pub hazard_backend: Option<String>,
    /// Tasks that failed for good during the flight, with their last error; the mission flew on
    /// without them.
    pub failed_tasks: Vec<String>,
    /// Configured tasks that could not run in this build, and why.
    pub skipped_tasks: Vec<String>,
    /// Simulated seconds per wall-clock second.
    pub speedup: f64,
    /// How well the runtime knew where the pad was while it tracked it; `None` when no
    /// relative state with a recent vision fix came in.
    pub localisation: Option<LocalisationError>,
    #[serde(skip)]
    pub track: Vec<TrackSample>,
    /// Wall time of one turn of the runtime's loop (the tasks run inside it in lockstep), µs.
    pub loop_step_p50_us: f64,
    pub loop_step_p99_us: f64,
    /// From a frame's capture to the first velocity setpoint that answered its fix (camera
    /// delivery and the runtime's own delay), ms: p50, p99, max, and over how many fixes;
    /// `None` when none answered one.
    pub capture_to_setpoint_ms: Option<[f64; 3]>,
    pub capture_to_setpoint_fixes: u64,
    /// From the frame's arrival at the runtime to that setpoint (the runtime's own share),
    /// ms: p50, p99, max.
    pub delivered_to_setpoint_ms: Option<[f64; 3]>,
    /// Every change of the tasks' levels (with `record_track`).
    #[serde(skip)]
    pub qos_track: Vec<QosSample>,
}

/// The runtime's estimate of the UAV's position relative to the pad (the tracker's
/// `RelativeState`) against the truth, over the samples taken while tracking.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LocalisationError {
    pub samples: usize,
    /// Root mean square and largest horizontal error, metres.
    pub horizontal_rms_m: f64,
    pub horizontal_max_m: f64,
    /// Root mean square error of the height above the pad, metres.
    pub vertical_rms_m: f64,
    /// Root mean square error of the platform's horizontal velocity, over the samples that had
    /// an estimate of it; `None` when none had.
    pub platform_velocity_rms_m_s: Option<f64>,
}

/// The summary of many runs.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SimSummary {
    pub runs: usize,
    pub success_rate: f64,
    pub touchdown_error_p50_m: Option<f64>,
    pub touchdown_error_p95_m: Option<f64>,
    pub time_to_land_p50_s: Option<f64>,
    /// Over every run that touched down (pad or not): how hard and how leaning.
    pub touchdown_vertical_speed_p95_m_s: Option<f64>,
    pub touchdown_tilt_p95_deg: Option<f64>,
    pub blind_before_contact_p95_s: Option<f64>,
    pub energy_mean_wh: f64,
    pub companion_energy_mean_wh: f64,
}

/// The `p` quantile (0..=1) of `values` by linear interpolation between order statistics;
/// `None` for no values.
pub fn quantile(values: &[f64], p: f64) -> Option<f64> {
    if values.is_empty() {
        return None;
    }
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    let position = p.clamp(0.0, 1.0) * (sorted.len() - 1) as f64;
    let below = position.floor() as usize;
    let above = position.ceil() as usize;
    let fraction = position - below as f64;
    Some(sorted[below] + fraction * (sorted[above] - sorted[below]))
}

impl SimSummary {
    /// Success = touched down on the pad. Touchdown errors and times count successful runs.
    pub fn of(outcomes: &[SimOutcome]) -> Self {
        let runs = outcomes.len();
        let successes: Vec<&SimOutcome> = outcomes.iter().filter(|o| o.landed_on_pad).collect();
        let errors: Vec<f64> = successes
            .iter()
            .filter_map(|o| o.touchdown_error_m)
            .collect();
        let times: Vec<f64> = successes.iter().filter_map(|o| o.time_to_land_s).collect();
        let of_touchdowns = |f: &dyn Fn(&SimOutcome) -> Option<f64>| {
            let values: Vec<f64> = outcomes.iter().filter_map(f).collect();
            quantile(&values, 0.95)
        };
        let mean = |f: &dyn Fn(&SimOutcome) -> f64| {
            if runs == 0 {
                0.0
            } else {
                outcomes.iter().map(f).sum::<f64>() / runs as f64
            }
        };
        Self {
            runs,
            success_rate: if runs == 0 {
                0.0
            } else {
                successes.len() as f64 / runs as f64
            },
            touchdown_error_p50_m: quantile(&errors, 0.5),
            touchdown_error_p95_m: quantile(&errors, 0.95),
            time_to_land_p50_s: quantile(&times, 0.5),
            touchdown_vertical_speed_p95_m_s: of_touchdowns(&|o| o.touchdown_vertical_speed_m_s),
            touchdown_tilt_p95_deg: of_touchdowns(&|o| o.touchdown_tilt_deg),
            blind_before_contact_p95_s: of_touchdowns(&|o| o.blind_before_contact_s),
            energy_mean_wh: mean(&|o| o.flight_energy_wh + o.companion_energy_wh),
            companion_energy_mean_wh: mean(&|o| o.companion_energy_wh),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_interpolate_between_order_statistics() {
        assert_eq!(quantile(&[], 0.5), None);
        assert_eq!(quantile(&[3.0], 0.95), Some(3.0));
        // 1..=11: the median is 6; p95 sits at position 9.5 → 10.5.
        let values: Vec<f64> = (1..=11).rev().map(f64::from).collect();
        assert_eq!(quantile(&values, 0.5), Some(6.0));
        assert_eq!(quantile(&values, 0.95), Some(10.5));
        assert_eq!(quantile(&values, 0.0), Some(1.0));
        assert_eq!(quantile(&values, 1.0), Some(11.0));
    }

    fn outcome(on_pad: bool, error_m: f64, energy_wh: f64) -> SimOutcome {
        SimOutcome {
            landed_on_pad: on_pad,
            touched_down: true,
            touchdown_error_m: Some(error_m),
            time_to_land_s: Some(30.0),
            flight_energy_wh: energy_wh,
            companion_energy_wh: 1.0,
            ..SimOutcome::default()
        }
    }

    #[test]
    fn the_summary_counts_only_pad_landings_as_successes() {
        let outcomes = [
            outcome(true, 0.1, 10.0),
            outcome(true, 0.3, 12.0),
            outcome(false, 2.0, 14.0),
            outcome(true, 0.2, 16.0),
        ];
        let summary = SimSummary::of(&outcomes);
        assert_eq!(summary.runs, 4);
        assert_eq!(summary.success_rate, 0.75);
        // The miss's 2 m is not among the touchdown errors.
        assert_eq!(summary.touchdown_error_p50_m, Some(0.2));
        assert!((summary.touchdown_error_p95_m.unwrap() - 0.29).abs() < 1e-12);
        assert_eq!(summary.energy_mean_wh, 14.0);
        assert_eq!(summary.companion_energy_mean_wh, 1.0);
    }

    #[test]
    fn the_blind_time_before_contact_counts_every_touchdown_that_had_a_fix() {
        let blind = |on_pad, blind_s| SimOutcome {
            blind_before_contact_s: blind_s,
            ..outcome(on_pad, 0.1, 10.0)
        };
        // The miss off the pad counts (it is how it missed); a run without a fix does not.
        let outcomes = [
            blind(true, Some(0.1)),
            blind(false, Some(0.9)),
            blind(true, None),
        ];
        let summary = SimSummary::of(&outcomes);
        assert!((summary.blind_before_contact_p95_s.unwrap() - 0.86).abs() < 1e-12);
        assert_eq!(SimSummary::of(&[]).blind_before_contact_p95_s, None);
    }
}
