//! `qosrt model`: describe a power profile's model, evaluate it at a point, and measure its
//! leave-one-out error.

use crate::check::{report_failure, EXIT_INVALID_CONFIG};
use power_models::grid::{leave_one_out_profile, AxisScale, GridModel, LooReport, ModelError};
use power_models::profile::Profile;
use runtime::diagnostic::{Diagnostic, FileReport};
use serde::Serialize;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

pub struct ModelArgs {
    pub profile: PathBuf,
    pub loo: bool,
    /// `knob=value` pairs.
    pub at: Vec<String>,
    pub scale: Option<AxisScale>,
    /// Names of a powprofiler CSV's knob columns (200, 201, …), in order.
    pub knob_names: Vec<String>,
    pub json: bool,
}

#[derive(Serialize)]
struct ModelReport<'a> {
    profile: String,
    board: &'a str,
    meter: &'a str,
    source: Option<&'a str>,
    scale: AxisScale,
    knobs: Vec<KnobAxis>,
    measured_points: usize,
    inferred_points: Vec<Vec<f64>>,
    #[serde(skip_serializing_if = "Option::is_none")]
    evaluation: Option<PointEvaluation>,
    #[serde(skip_serializing_if = "Option::is_none")]
    leave_one_out: Option<LooReport>,
}

#[derive(Serialize)]
struct KnobAxis {
    name: String,
    grid: Vec<f64>,
}

#[derive(Serialize)]
struct PointEvaluation {
    knobs: Vec<(String, f64)>,
    power_w: f64,
    extrapolated: bool,
    clamped_knobs: Vec<String>,
}

pub fn run(args: &ModelArgs) -> ExitCode {
    let profile = match read_profile(&args.profile, &args.knob_names) {
        Ok(profile) => profile,
        Err(report) => {
            report_failure(&report, args.json);
            return ExitCode::from(EXIT_INVALID_CONFIG);
        }
    };
    match describe(&profile, args) {
        Ok(report) => {
            crate::output::print_result(args.json, &report, human);
            ExitCode::SUCCESS
        }
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::from(EXIT_INVALID_CONFIG)
        }
    }
}

/// Reads a TOML profile, or a powprofiler CSV (by its `.csv` extension).
fn read_profile(path: &Path, knob_names: &[String]) -> Result<Profile, FileReport> {
    let failure = |source: String, diagnostic: Diagnostic| FileReport {
        path: path.to_path_buf(),
        source,
        diagnostics: vec![diagnostic],
    };
    let source = std::fs::read_to_string(path).map_err(|error| {
        failure(
            String::new(),
            Diagnostic::error(None, format!("cannot read the profile: {error}")),
        )
    })?;
    let is_csv = path
        .extension()
        .is_some_and(|ext| ext.eq_ignore_ascii_case("csv"));
    let parsed = if is_csv {
        let names: Vec<&str> = knob_names.iter().map(String::as_str).collect();
        Profile::from_powprofiler_csv(&source, &names)
    } else {
        Profile::from_toml_str(&source)
    };
    parsed.map_err(|error| failure(source, Diagnostic::error(error.span, error.message)))
}

/// Why the model could not be described or evaluated.
#[derive(Debug, thiserror::Error)]
enum DescribeError {
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error("--at `{pair}`: expected KNOB=VALUE, e.g. hazard.rate_fps=2")]
    NotAPair { pair: String },
    #[error("--at `{pair}`: the model has no knob `{knob}`; its knobs are: {}", knobs.join(", "))]
    UnknownKnob {
        pair: String,
        knob: String,
        knobs: Vec<String>,
    },
    #[error("--at `{pair}`: `{value}` is not a number")]
    NotANumber { pair: String, value: String },
    #[error("--at: knob `{knob}` is given twice")]
    Twice { knob: String },
    #[error("--at: give a value for every knob; missing: {}", missing.join(", "))]
    Missing { missing: Vec<String> },
}

fn describe<'a>(profile: &'a Profile, args: &ModelArgs) -> Result<ModelReport<'a>, DescribeError> {
    let scale = args.scale.unwrap_or_default();
    let model = GridModel::from_profile(profile, scale)?;
    let evaluation = if args.at.is_empty() {
        None
    } else {
        Some(evaluate(&model, &args.at)?)
    };
    let leave_one_out = if args.loo {
        Some(leave_one_out_profile(profile, scale)?)
    } else {
        None
    };
    Ok(ModelReport {
        profile: args.profile.display().to_string(),
        board: &profile.board,
        meter: &profile.meter,
        source: profile.source.as_deref(),
        scale,
        knobs: model
            .knob_names()
            .iter()
            .zip(model.axes())
            .map(|(name, grid)| KnobAxis {
                name: name.clone(),
                grid: grid.clone(),
            })
            .collect(),
        measured_points: profile.samples.len(),
        inferred_points: model.inferred_points(),
        evaluation,
        leave_one_out,
    })
}

/// Evaluates the model at `knob=value` pairs, which must name every knob once.
fn evaluate(model: &GridModel, pairs: &[String]) -> Result<PointEvaluation, DescribeError> {
    let names = model.knob_names();
    let mut point = vec![None; names.len()];
    for pair in pairs {
        let (name, value) = pair
            .split_once('=')
            .ok_or_else(|| DescribeError::NotAPair { pair: pair.clone() })?;
        let index = names.iter().position(|n| n == name.trim()).ok_or_else(|| {
            DescribeError::UnknownKnob {
                pair: pair.clone(),
                knob: name.trim().to_string(),
                knobs: names.to_vec(),
            }
        })?;
        let value: f64 = value
            .trim()
            .parse()
            .ok()
            .filter(|v: &f64| v.is_finite())
            .ok_or_else(|| DescribeError::NotANumber {
                pair: pair.clone(),
                value: value.trim().to_string(),
            })?;
        if point[index].replace(value).is_some() {
            return Err(DescribeError::Twice {
                knob: name.to_string(),
            });
        }
    }
    let missing: Vec<String> = names
        .iter()
        .zip(&point)
        .filter(|(_, v)| v.is_none())
        .map(|(n, _)| n.clone())
        .collect();
    if !missing.is_empty() {
        return Err(DescribeError::Missing { missing });
    }
    let point: Vec<f64> = point.into_iter().flatten().collect();
    let evaluation = model.try_eval(&point)?;
    Ok(PointEvaluation {
        knobs: names.iter().cloned().zip(point.iter().copied()).collect(),
        power_w: evaluation.value,
        extrapolated: evaluation.extrapolated,
        clamped_knobs: names
            .iter()
            .enumerate()
            .filter(|(i, _)| evaluation.is_clamped(*i))
            .map(|(_, n)| n.clone())
            .collect(),
    })
}

fn human(report: &ModelReport) -> String {
    let mut out = format!(
        "profile {}\n  board: {}\n  meter: {}\n",
        report.profile, report.board, report.meter
    );
    if let Some(source) = report.source {
        out += &format!("  source: {source}\n");
    }
    out += &format!(
        "model: multilinear interpolation on {} axes; {} measured point(s), {} inferred\n",
        match report.scale {
            AxisScale::Log => "log-scaled",
            AxisScale::Linear => "linear",
        },
        report.measured_points,
        report.inferred_points.len()
    );
    for knob in &report.knobs {
        out += &format!("  {}: {:?}\n", knob.name, knob.grid);
    }
    for point in &report.inferred_points {
        out += &format!("  inferred: {point:?}\n");
    }
    if let Some(evaluation) = &report.evaluation {
        let at: Vec<String> = evaluation
            .knobs
            .iter()
            .map(|(n, v)| format!("{n}={v}"))
            .collect();
        out += &format!("power at {}: {:.4} W", at.join(", "), evaluation.power_w);
        if evaluation.extrapolated {
            out += &format!(
                " (extrapolated: {} clamped to the grid)",
                evaluation.clamped_knobs.join(", ")
            );
        }
        out += "\n";
    }
    if let Some(loo) = &report.leave_one_out {
        out += "leave-one-out (each measured point predicted by the model without it):\n";
        for point in &loo.per_point {
            out += &format!(
                "  {:<24} measured {:>8.4} W  predicted {:>8.4} W  error {:>6.2} %\n",
                format!("{:?}", point.knobs),
                point.measured_w,
                point.predicted_w,
                point.abs_pct_error
            );
        }
        out += &format!("  MAPE {:.2} %\n", loo.mape_pct);
    }
    out
}
