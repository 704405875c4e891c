//! The QoS sweep of `qosrt profile`: the configured tasks of one mission phase run in the
//! real-time scheduler on synthetic inputs (the dry run's rendered frames and hovering vehicle)
//! at each chosen combination of their QoS levels, while a [`PowerMeter`] is sampled at a steady
//! rate; the warm-up after each change is discarded, and the board's idle power (no task
//! running) is measured first. The result becomes a [`Profile`], the format `plan` reads.
//!
//! Choosing the combinations ([`plan_sweep`]) and turning readings into a profile
//! ([`summarise`], [`to_profile`]) are pure; [`run_sweep`] does the running and the reading.

use crate::config::MissionConfig;
use crate::dry_run::{hovering_vehicle, synthetic_frames, FRAME_PERIOD};
use crate::power_meter::{MeterError, PowerMeter, PowerReading};
use crate::registry::PluginRegistry;
use crate::scheduler::{
    RealTimeOptions, RealTimeScheduler, SchedulerBuilder, SchedulerError, TaskId,
};
use crate::task::TaskHealth;
use crate::topics::{CameraFrame, VehicleState, CAMERA_FRAME, VEHICLE_STATE};
use power_models::profile::{ChannelStats, Profile, Sample};
use std::str::FromStr;
use std::time::{Duration, Instant};

/// A sweep aborts a point when more of its readings than this fraction fail.
const MAX_FAILED_READ_FRACTION: f64 = 0.1;
/// A meter below this fraction of the requested rate is reported.
const RATE_TOLERANCE: f64 = 0.9;
/// A task below this fraction of its nominal rate is reported (it cannot keep its level).
const TASK_RATE_TOLERANCE: f64 = 0.8;
/// Fewer activations than this in a point's window make its power a poor sample of the level.
const MIN_ACTIVATIONS: f64 = 3.0;
/// The activations per window the warning above asks for.
const FAIR_ACTIVATIONS: f64 = 10.0;

#[derive(Debug, thiserror::Error)]
pub enum SweepError {
    #[error("--levels `{text}`: {message}")]
    BadLevels { text: String, message: String },
    #[error("unknown phase `{phase}`; the config's phases are: {known}")]
    UnknownPhase { phase: String, known: String },
    #[error("--levels {knob}: no task that runs in phase `{phase}` has this knob; those tasks' knobs are: {known}")]
    UnknownKnob {
        knob: String,
        phase: String,
        known: String,
    },
    #[error("--levels {knob}={value}: not one of the task's levels [{levels}]")]
    NotALevel {
        knob: String,
        value: f64,
        levels: String,
    },
    #[error("--levels {knob} is given twice")]
    KnobTwice { knob: String },
    #[error("--levels {knob}: task `{task}` cannot run here: its plugin `{plugin}` is not built into this binary")]
    KnobOfSkippedTask {
        knob: String,
        task: String,
        plugin: String,
    },
    #[error("phase `{phase}` has no task this binary can run{skipped}")]
    NothingToRun { phase: String, skipped: String },
    #[error("bad sweep option: {0}")]
    Options(String),
    #[error(transparent)]
    Scheduler(#[from] SchedulerError),
    #[error("synthetic inputs: {0}")]
    Frames(#[source] crate::dry_run::DryRunError),
    #[error("synthetic inputs: {0}")]
    Inputs(#[source] crate::bus::BusError),
    #[error("meter {meter}: {failed} of {attempts} readings failed while measuring {point}; the last: {last}")]
    MeterFailed {
        meter: String,
        point: String,
        failed: usize,
        attempts: usize,
        last: Box<MeterError>,
    },
    #[error("meter {meter}: {readings} reading(s) in the {window_s:.2} s window of {point}, at least 2 are needed: lengthen --duration-s or raise --rate-hz")]
    TooFewReadings {
        meter: String,
        point: String,
        readings: usize,
        window_s: f64,
    },
}

mod plan;
mod run;

#[cfg(test)]
use run::{measure, NoInputs};

pub use plan::{plan_sweep, LevelChoice, SkippedTask, SweepPlan, SweptKnob};
pub use run::{run_sweep, PointResult, SweepObserver, SweepOptions, SweepResult, TaskRate};

/// What one point's readings came to.
#[derive(Debug, Clone, PartialEq)]
pub struct Measurement {
    pub readings: usize,
    /// Length of the measuring window (after the warm-up).
    pub window_s: f64,
    pub total: ChannelStats,
    pub cpu: Option<ChannelStats>,
    pub gpu: Option<ChannelStats>,
    /// Readings per second in the window.
    pub achieved_rate_hz: f64,
    pub failed_reads: usize,
    /// The slowest meter read, in ms.
    pub slowest_read_ms: f64,
}

/// Mean and spread of a window's readings; `None` below 2 readings. The CPU and GPU rails
/// count only where every reading has them.
pub fn summarise(readings: &[PowerReading], window_s: f64) -> Option<Measurement> {
    let total: Vec<f64> = readings.iter().map(|r| r.total_w).collect();
    let rail = |pick: fn(&PowerReading) -> Option<f64>| {
        let values: Option<Vec<f64>> = readings.iter().map(pick).collect();
        values.and_then(|v| ChannelStats::of(&v))
    };
    Some(Measurement {
        readings: readings.len(),
        window_s,
        total: ChannelStats::of(&total)?,
        cpu: rail(|r| r.cpu_w),
        gpu: rail(|r| r.gpu_w),
        achieved_rate_hz: if window_s > 0.0 {
            readings.len() as f64 / window_s
        } else {
            0.0
        },
        failed_reads: 0,
        slowest_read_ms: 0.0,
    })
}

/// The sweep as a profile: one sample per combination (knobs in the order of the plan's
/// axes), and the idle baseline. `source` says how it was measured.
pub fn to_profile(
    plan: &SweepPlan,
    result: &SweepResult,
    board: &str,
    meter: &str,
    rate_hz: f64,
    source: String,
) -> Profile {
    Profile {
        board: board.to_string(),
        meter: meter.to_string(),
        sample_rate_hz: Some(rate_hz),
        source: Some(source),
        idle_power_w: Some(result.idle.total.mean_w),
        idle_power_std_w: Some(result.idle.total.std_w),
        knobs: plan.axes.iter().map(|axis| axis.name.clone()).collect(),
        samples: result
            .points
            .iter()
            .map(|point| Sample {
                knobs: point.values.clone(),
                power_w: point.measurement.total.mean_w,
                power_std_w: Some(point.measurement.total.std_w),
                duration_s: Some(point.measurement.window_s),
                cpu_power_w: point.measurement.cpu.map(|c| c.mean_w),
                gpu_power_w: point.measurement.gpu.map(|c| c.mean_w),
            })
            .collect(),
    }
}

/// How the sweep was run, in words, for the profile's `source`.
pub fn describe_method(plan: &SweepPlan, config: &MissionConfig, options: &SweepOptions) -> String {
    let mut text = format!(
        "qosrt profile: phase `{}` of mission `{}`, each point {} s after {} s of warm-up, meter read at {} Hz, tasks on synthetic rendered frames",
        plan.phase,
        config.mission.name,
        options.duration.as_secs_f64(),
        options.warmup.as_secs_f64(),
        options.rate_hz
    );
    if !plan.held.is_empty() {
        let held: Vec<String> = plan
            .held
            .iter()
            .map(|k| format!("{} = {}", k.name, k.values[0]))
            .collect();
        text += &format!("; held: {}", held.join(", "));
    }
    if !plan.skipped.is_empty() {
        let skipped: Vec<String> = plan
            .skipped
            .iter()
            .map(|s| format!("{} (plugin {})", s.task, s.plugin))
            .collect();
        text += &format!("; not run (plugin not built in): {}", skipped.join(", "));
    }
    text
}

#[cfg(test)]
mod tests;
