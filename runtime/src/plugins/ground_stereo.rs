//! The `ground_stereo` plugin: the ground-based long-baseline PTU stereo localisation of seed 001
//! as a task. Each activation reads the newest pair of PTU readings (pan, tilt and the tracked
//! target's pixel offset on each side) from [`PTU_PAIR`], turns them into lines of sight (Eq. 5),
//! triangulates them (the common perpendicular of Eqs. 8–14, or the closed form of Eq. 6) and
//! publishes the target's position in the runway frame on [`GROUND_STEREO_FIX`]: a localisation
//! source for a fixed-wing approach that needs no GNSS on board.
//!
//! A bad pair (a lost target, a non-finite number, near-parallel lines of sight) is published as
//! its named error and counted; the task keeps running, because the next frame is usually fine.
//!
//! [`fly_scripted_approach`] flies the scripted approach of `algorithms::stereo::approach`
//! through this plugin on the bus, in virtual time (`qosrt ptu-stereo approach`).

use crate::bus::{BusError, Publisher, Subscriber};
use crate::catalog::{PluginInfo, Port};
use crate::clock::Timestamp;
use crate::config::{Knob, Resource, TaskConfig};
use crate::registry::{PluginRegistry, RegistryError};
use crate::scheduler::{SchedulerBuilder, SchedulerError, TaskStats};
use crate::task::{Task, TaskBuild, TaskContext, TaskError};
use crate::topics::{GroundStereoFix, PtuPairReading, GROUND_STEREO_FIX, PTU_PAIR};
use algorithms::stereo::approach::{ApproachConfig, ApproachError, ApproachFrames};
use algorithms::stereo::triangulation::{
    CameraIntrinsics, Estimator, StereoFix, StereoRig, TriangulationError, DEFAULT_MIN_DET_H,
};
use nalgebra::Vector3;
use serde::Deserialize;

pub const PLUGIN_NAME: &str = "ground_stereo";

#[derive(Debug, Clone, Copy, Default, Deserialize, PartialEq)]
#[serde(rename_all = "snake_case")]
enum EstimatorParam {
    /// Eq. 14: the weighted point of the common perpendicular.
    #[default]
    CommonPerpendicular,
    /// Eq. 6: the horizontal crossing, at the left line of sight's height.
    ClosedForm,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Distance between the PTUs' rotation centres (the seed: 10 m).
    #[serde(default = "default_baseline")]
    baseline_m: f64,
    /// The left PTU's rotation centre in the runway frame (origin at the touchdown point, Y out
    /// along the centre line towards the approach, Z up, X to the right seen from the PTUs);
    /// default: D/2 to the left of the touchdown point.
    #[serde(default)]
    left_ptu_runway_m: Option<[f64; 3]>,
    /// The baseline's direction: the runway's X turned this far about Z (counterclockwise from
    /// above); 0 when the baseline is square to the centre line.
    #[serde(default)]
    baseline_yaw_deg: f64,
    /// The seed's 100 mm lens.
    #[serde(default = "default_focal_length")]
    focal_length_mm: f64,
    /// The seed's DFK 23G445 (Sony ICX445): 3.75 µm pixels.
    #[serde(default = "default_pixel_pitch")]
    pixel_pitch_um: f64,
    #[serde(default)]
    estimator: EstimatorParam,
    /// w of Eq. 14 (common perpendicular only).
    #[serde(default = "default_weight")]
    weight_left: f64,
    /// Refuse pairs whose det H (sin² of the angle between the lines of sight) is below this.
    #[serde(default = "default_min_det_h")]
    min_det_h: f64,
}

fn default_baseline() -> f64 {
    10.0
}
fn default_focal_length() -> f64 {
    CameraIntrinsics::SEED_FOCAL_LENGTH_MM
}
fn default_pixel_pitch() -> f64 {
    CameraIntrinsics::SEED_PIXEL_PITCH_UM
}
fn default_weight() -> f64 {
    0.5
}
fn default_min_det_h() -> f64 {
    DEFAULT_MIN_DET_H
}

pub fn register(registry: &mut PluginRegistry) -> Result<(), RegistryError> {
    super::register_builtin(registry, PLUGIN_NAME, GroundStereoTask::new)
}

struct GroundStereoTask {
    rig: StereoRig,
    located: u64,
    rejected: u64,
    missed: u64,
    last_seq: u64,
    readings: Subscriber<PtuPairReading>,
    output: Publisher<GroundStereoFix>,
}

impl GroundStereoTask {
    fn new(params: Params, build: &TaskBuild<'_>) -> Result<Self, TaskError> {
        let bad = |e: &dyn std::fmt::Display| TaskError::Params(e.to_string());
        let camera = CameraIntrinsics::new(params.focal_length_mm, params.pixel_pitch_um)
            .map_err(|e| bad(&e))?;
        let estimator = match params.estimator {
            EstimatorParam::CommonPerpendicular => Estimator::CommonPerpendicular {
                weight_left: params.weight_left,
            },
            EstimatorParam::ClosedForm => Estimator::ClosedForm,
        };
        let left = params
            .left_ptu_runway_m
            .map(Vector3::from)
            .unwrap_or_else(|| Vector3::new(-params.baseline_m / 2.0, 0.0, 0.0));
        let rig = StereoRig::new(
            params.baseline_m,
            left,
            params.baseline_yaw_deg.to_radians(),
            camera,
            estimator,
            params.min_det_h,
        )
        .map_err(|e| bad(&e))?;
        Ok(Self {
            rig,
            located: 0,
            rejected: 0,
            missed: 0,
            last_seq: 0,
            readings: build.input(PTU_PAIR)?,
            output: build.output(GROUND_STEREO_FIX)?,
        })
    }

    fn locate(&mut self, pair: &PtuPairReading) -> Result<StereoFix, TriangulationError> {
        let result = self.rig.locate(&pair.left, &pair.right);
        match &result {
            Ok(_) => self.located += 1,
            Err(_) => self.rejected += 1,
        }
        result
    }
}

impl Task for GroundStereoTask {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let Some(message) = self.readings.take_new() else {
            return Ok(());
        };
        self.missed += message.seq.saturating_sub(self.last_seq + 1);
        self.last_seq = message.seq;
        let pair = message.value;
        let result = self.locate(&pair);
        if let Err(error) = &result {
            // The first refusal and then every doubling: a broken PTU stream is seen without
            // flooding the log at the camera's frame rate.
            if self.rejected.is_power_of_two() {
                tracing::warn!(
                    task = ctx.name(),
                    %error,
                    rejected = self.rejected,
                    located = self.located,
                    "PTU pair refused"
                );
            } else {
                tracing::debug!(task = ctx.name(), %error, "PTU pair refused");
            }
        }
        self.output.publish(
            ctx.now(),
            GroundStereoFix {
                time_s: pair.time_s,
                result,
                located: self.located,
                rejected: self.rejected,
                missed: self.missed,
            },
        );
        Ok(())
    }
}

/// Publishes the scripted approach's PTU readings, one pair per activation.
struct ScriptedPtus {
    frames: ApproachFrames,
    output: Publisher<PtuPairReading>,
}

impl Task for ScriptedPtus {
    fn step(&mut self, ctx: &mut TaskContext<'_>) -> Result<(), TaskError> {
        let Some(frame) = self.frames.next() else {
            return Ok(());
        };
        self.output.publish(
            ctx.now(),
            PtuPairReading {
                time_s: frame.time_s,
                left: frame.left,
                right: frame.right,
            },
        );
        Ok(())
    }
}

/// Why the scripted approach could not be flown.
#[derive(Debug, thiserror::Error)]
pub enum ScriptedApproachError {
    #[error(transparent)]
    Approach(#[from] ApproachError),
    #[error(transparent)]
    Registry(#[from] RegistryError),
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error(transparent)]
    Bus(#[from] BusError),
    #[error("the frame rate {0} Hz gives no whole-microsecond frame period")]
    FrameRate(f64),
}

/// One fix of the scripted approach, with the truth at its capture time.
#[derive(Debug, Clone, PartialEq)]
pub struct ScriptedFix {
    pub time_s: f64,
    pub truth_runway_m: Vector3<f64>,
    pub result: Result<StereoFix, TriangulationError>,
}

/// What the plugin made of the scripted approach.
#[derive(Debug, Clone)]
pub struct ScriptedApproach {
    pub fixes: Vec<ScriptedFix>,
    /// The plugin's counters after the last frame.
    pub located: u64,
    pub rejected: u64,
    pub missed: u64,
    pub stats: Option<TaskStats>,
}

fn task_config(name: &str, plugin: &str, period_ms: f64, params: toml::Table) -> TaskConfig {
    TaskConfig {
        name: name.into(),
        plugin: plugin.into(),
        resource: Resource::Cpu,
        cores: vec![],
        phases: vec!["approach".into()],
        weight: 1.0,
        knob: Knob::PeriodMs,
        levels: vec![period_ms],
        utility: vec![1.0],
        restart: None,
        params,
        trigger: Default::default(),
        max_idle_ms: None,
        config_dir: None,
        camera: Default::default(),
    }
}

/// Flies `config`'s approach: a scripted task publishes each frame's PTU pair, the
/// `ground_stereo` task (set up with `config`'s rig and `extra_params`, e.g. its estimator) runs
/// at the same rate, and every fix is collected with the truth at its capture time.
pub fn fly_scripted_approach(
    config: &ApproachConfig,
    extra_params: &toml::Table,
) -> Result<ScriptedApproach, ScriptedApproachError> {
    config.validate()?;
    let period_us = (1e6 / config.frame_rate_hz).round();
    if !(period_us >= 1.0 && period_us.is_finite()) {
        return Err(ScriptedApproachError::FrameRate(config.frame_rate_hz));
    }
    let period_ms = period_us / 1000.0;
    let rig = config.rig()?;
    let mut registry = PluginRegistry::new();
    register(&mut registry)?;
    let approach = *config;
    let source = PluginInfo {
        summary: "the scripted approach's PTU readings, one pair per activation",
        outputs: const { &[Port::of(PTU_PAIR)] },
        ..PluginInfo::user("scripted_ptu_pair")
    };
    registry.register_plugin(source, move |build| {
        Ok(Box::new(ScriptedPtus {
            frames: approach
                .frames()
                .map_err(|e| TaskError::Params(e.to_string()))?,
            output: build.output(PTU_PAIR)?,
        }) as Box<dyn Task>)
    })?;
    let mut params = toml::Table::new();
    params.insert("baseline_m".into(), config.baseline_m.into());
    let left = rig.left_ptu_runway_m();
    params.insert(
        "left_ptu_runway_m".into(),
        toml::Value::Array(vec![left.x.into(), left.y.into(), left.z.into()]),
    );
    params.insert(
        "focal_length_mm".into(),
        config.camera.focal_length_mm().into(),
    );
    params.insert(
        "pixel_pitch_um".into(),
        config.camera.pixel_pitch_um().into(),
    );
    for (key, value) in extra_params {
        params.insert(key.clone(), value.clone());
    }
    let mut builder = SchedulerBuilder::new(&registry);
    // The source first: at each frame instant it publishes before the stereo task reads.
    builder.task(&task_config(
        "ptus",
        "scripted_ptu_pair",
        period_ms,
        toml::Table::new(),
    ));
    builder.task(&task_config(
        "ground_stereo",
        PLUGIN_NAME,
        period_ms,
        params,
    ));
    let mut scheduler = builder.build_virtual()?;
    let mut fixes_topic = scheduler
        .bus()
        .subscriber::<GroundStereoFix>(GROUND_STEREO_FIX)?;
    scheduler.start()?;
    let mut fixes = Vec::with_capacity(config.frame_count());
    let (mut located, mut rejected, mut missed) = (0, 0, 0);
    for frame in 0..config.frame_count() {
        let at = Timestamp::from_micros(frame as u64 * period_us as u64);
        scheduler.run_until(at)?;
        if let Some(message) = fixes_topic.take_new() {
            let fix = &message.value;
            (located, rejected, missed) = (fix.located, fix.rejected, fix.missed);
            fixes.push(ScriptedFix {
                time_s: fix.time_s,
                truth_runway_m: config.truth_at(fix.time_s),
                result: fix.result.clone(),
            });
        }
    }
    let stats = scheduler.task_stats("ground_stereo");
    scheduler.stop();
    Ok(ScriptedApproach {
        fixes,
        located,
        rejected,
        missed,
        stats,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bus::Bus;
    use crate::task::{MissionHealth, QosLevel};
    use crate::topics::PtuReading;
    use algorithms::stereo::approach::{interval_table, FixError};
    use algorithms::stereo::triangulation::{LineOfSight, Side};

    fn task(params: &str) -> Result<GroundStereoTask, TaskError> {
        task_on(&Bus::new(), params)
    }

    fn task_on(bus: &Bus, params: &str) -> Result<GroundStereoTask, TaskError> {
        let config = task_config(
            PLUGIN_NAME,
            PLUGIN_NAME,
            40.0,
            toml::from_str(params).unwrap(),
        );
        super::super::build_for_test(&config, bus, |build| {
            GroundStereoTask::new(build.parse_params()?, build)
        })
    }

    #[test]
    fn params_build_the_rig_with_named_errors() {
        let default = task("").unwrap();
        assert_eq!(default.rig.baseline_m(), 10.0);
        assert_eq!(
            default.rig.left_ptu_runway_m(),
            Vector3::new(-5.0, 0.0, 0.0)
        );
        assert_eq!(
            default.rig.right_ptu_runway_m(),
            Vector3::new(5.0, 0.0, 0.0)
        );
        assert_eq!(default.rig.camera().pixel_pitch_um(), 3.75);
        assert_eq!(
            default.rig.estimator(),
            Estimator::CommonPerpendicular { weight_left: 0.5 }
        );
        let closed = task("estimator = \"closed_form\"\nbaseline_m = 20.0").unwrap();
        assert_eq!(closed.rig.estimator(), Estimator::ClosedForm);
        assert_eq!(
            closed.rig.left_ptu_runway_m(),
            Vector3::new(-10.0, 0.0, 0.0)
        );
        let placed = task(
            "left_ptu_runway_m = [-6.0, -30.0, 1.5]\nbaseline_m = 12.0\nbaseline_yaw_deg = 90.0",
        )
        .unwrap();
        let right = placed.rig.right_ptu_runway_m();
        assert!(
            (right - Vector3::new(-6.0, -18.0, 1.5)).norm() < 1e-9,
            "{right:?}"
        );
        for (params, names) in [
            ("estimator = \"ransac\"", "ransac"),
            ("baseline_m = 0.0", "baseline_m"),
            ("focal_length_mm = -100.0", "focal_length_mm"),
            ("pixel_pitch_um = 0.0", "pixel_pitch_um"),
            ("weight_left = 2.0", "[0, 1]"),
            ("baseline = 10.0", "baseline"),
        ] {
            let Err(TaskError::Params(why)) = task(params) else {
                panic!("{params} must be refused");
            };
            assert!(why.contains(names), "{params}: {why}");
        }
    }

    fn reading(from: Vector3<f64>, target: Vector3<f64>) -> PtuReading {
        // Pointing a little off the target so the pixel offset matters.
        let exact = LineOfSight::towards(&from, &target).unwrap();
        let pan_p = exact.pan_rad - 2e-4;
        let focal_px = 100_000.0 / 3.75;
        PtuReading {
            pan_rad: pan_p,
            tilt_rad: exact.tilt_rad,
            // Eq. 5 inverted for an untilted offset: u = f·tan(ψ − ψp).
            target_offset_px: Some([focal_px * (2e-4f64).tan(), 0.0]),
        }
    }

    /// Driven by hand on a bus: a good pair is located, bad ones are published as named errors
    /// and counted while the task keeps stepping.
    #[test]
    fn bad_pairs_are_published_and_counted_without_failing_the_task() {
        let bus = Bus::new();
        let mut stereo = task_on(&bus, "left_ptu_runway_m = [-5.0, -20.0, 0.0]").unwrap();
        let level = QosLevel {
            index: 0,
            knob: Knob::PeriodMs,
            value: 40.0,
            period_ms: 40.0,
        };
        let health = MissionHealth::new(vec!["ground_stereo".into()]);
        let pairs = bus.publisher::<PtuPairReading>(PTU_PAIR).unwrap();
        let mut fixes = bus
            .subscriber::<GroundStereoFix>(GROUND_STEREO_FIX)
            .unwrap();
        let mut ctx = TaskContext::new("ground_stereo", Timestamp::ZERO, &level, &health, 0);
        stereo.start(&mut ctx).unwrap();
        // Nothing published yet: nothing to do, no fix.
        stereo.step(&mut ctx).unwrap();
        assert!(fixes.take_new().is_none());

        // The target 300 m out (runway frame), seen exactly: the stereo frame's origin is the
        // left PTU at (−5, −20, 0).
        let target_runway = Vector3::new(1.0, 300.0, 15.7);
        let target = target_runway - Vector3::new(-5.0, -20.0, 0.0);
        let good = PtuPairReading {
            time_s: 1.0,
            left: reading(Vector3::zeros(), target),
            right: reading(Vector3::new(10.0, 0.0, 0.0), target),
        };
        let mut nan = good;
        nan.time_s = 1.04;
        nan.right.tilt_rad = f64::NAN;
        let mut parallel = good;
        parallel.time_s = 1.08;
        parallel.right = parallel.left;
        parallel.right.pan_rad += 1e-8;
        let mut lost = good;
        lost.time_s = 1.12;
        lost.left.target_offset_px = None;
        let expected = [
            Ok(()),
            Err(TriangulationError::NonFinite {
                what: "right PTU tilt",
                value: f64::NAN,
            }),
            Err(TriangulationError::NearParallel {
                det_h: 0.0,
                min_det_h: DEFAULT_MIN_DET_H,
            }),
            Err(TriangulationError::NoTarget { side: Side::Left }),
        ];
        for (pair, expected) in [good, nan, parallel, lost].iter().zip(expected) {
            pairs.publish(Timestamp::ZERO, *pair);
            stereo
                .step(&mut ctx)
                .expect("a bad pair never fails the task");
            let fix = fixes.take_new().expect("one fix per pair").value.clone();
            assert_eq!(fix.time_s, pair.time_s);
            match (&fix.result, expected) {
                (Ok(located), Ok(())) => {
                    let error = (located.position_runway_m - target_runway).norm();
                    assert!(error < 1e-6, "{located:?}");
                }
                (Err(got), Err(want)) => {
                    assert_eq!(
                        std::mem::discriminant(got),
                        std::mem::discriminant(&want),
                        "{got}"
                    );
                    if let TriangulationError::NonFinite { what, .. } = got {
                        assert_eq!(*what, "right PTU tilt");
                    }
                }
                (got, want) => panic!("{got:?}, expected {want:?}"),
            }
        }
        // Still running, still locating; two readings published unseen count as missed.
        pairs.publish(Timestamp::ZERO, good);
        pairs.publish(Timestamp::ZERO, good);
        pairs.publish(Timestamp::ZERO, good);
        stereo.step(&mut ctx).unwrap();
        let last = fixes.take_new().unwrap().value.clone();
        assert!(last.result.is_ok());
        assert_eq!((last.located, last.rejected, last.missed), (2, 3, 2));
    }

    /// The scripted 3° approach through the plugin on the bus: every frame located, and the
    /// error shrinks as the aircraft comes in (Table 5's trend).
    #[test]
    fn the_scripted_approach_is_located_with_shrinking_errors() {
        let config = ApproachConfig::default();
        let run = fly_scripted_approach(&config, &toml::Table::new()).unwrap();
        assert_eq!(run.fixes.len(), config.frame_count());
        assert_eq!((run.rejected, run.missed), (0, 0));
        assert_eq!(run.located as usize, config.frame_count());
        let stats = run.stats.unwrap();
        assert_eq!(stats.failures, 0, "{stats:?}");
        // The fix at each capture time is compared with the truth then.
        let errors: Vec<FixError> = run
            .fixes
            .iter()
            .map(|f| FixError {
                distance_m: f.truth_runway_m.y,
                error_m: f.result.as_ref().unwrap().position_runway_m - f.truth_runway_m,
            })
            .collect();
        let rows = interval_table(&errors, 200.0).unwrap();
        assert_eq!(rows.len(), 5);
        for axis in 0..3 {
            for pair in rows.windows(2) {
                assert!(
                    pair[0].mean_abs_error_m[axis] > pair[1].mean_abs_error_m[axis],
                    "axis {axis}: {rows:#?}"
                );
            }
        }
        // Depth: σ ≈ y²·σθ·√2 / D, so 1000 m out is far worse than the last 200 m.
        let (far, near) = (&rows[0], &rows[4]);
        assert!(
            far.mean_abs_error_m[1] > 10.0 * near.mean_abs_error_m[1],
            "{rows:#?}"
        );
        // And the noise is what the seed's numbers say: at 800–1000 m (stereo depth ≈ 920 m)
        // the depth σ is 920²·√2·0.11 mrad / 10 m ≈ 13 m.
        assert!(
            (5.0..25.0).contains(&far.rms_error_m[1]),
            "{:?}",
            far.rms_error_m
        );
        // Same seed, same flight; the closed form also locates every frame.
        let again = fly_scripted_approach(&config, &toml::Table::new()).unwrap();
        assert_eq!(again.fixes, run.fixes);
        let mut closed = toml::Table::new();
        closed.insert("estimator".into(), "closed_form".into());
        let closed_run = fly_scripted_approach(&config, &closed).unwrap();
        assert_eq!(closed_run.rejected, 0);
    }
}
