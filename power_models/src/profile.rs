//! Measured power profiles: QoS knob values → mean power, with the board, meter and spread.
//!
//! Two readers: the project's own TOML format ([`Profile::from_toml_str`]) and powprofiler's
//! CSV ([`Profile::from_powprofiler_csv`], [`PowprofilerCsv`], [`summarise_trace`]). Both take
//! the text, never a path, and report mistakes as a [`ProfileError`] with the byte span of the
//! offending key, value or cell, so a caller can print `FILE:LINE:COL` with [`line_col`].

use std::ops::Range;

use serde::{Deserialize, Serialize};
use toml::Spanned;

mod powprofiler;

pub use powprofiler::{
    summarise_trace, Channel, ChannelStats, PowFlag, PowprofilerCsv, TraceSummary,
    POWPROFILER_DEFAULT_RATE_HZ,
};

/// A set of measured samples for one board and meter.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Profile {
    pub board: String,
    pub meter: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sample_rate_hz: Option<f64>,
    /// Free text naming where the figures come from.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// The board's mean power with none of the tasks running, measured with the samples: what
    /// the config's `power_model.idle_power_w` wants where profiles add up.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub idle_power_w: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub idle_power_std_w: Option<f64>,
    /// Knob names, `task.knob`; every sample's `knobs` follows this order.
    pub knobs: Vec<String>,
    #[serde(rename = "sample")]
    pub samples: Vec<Sample>,
}

/// One measured operating point.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Sample {
    /// Knob values in the order of [`Profile::knobs`].
    pub knobs: Vec<f64>,
    /// Mean total power over the sample.
    pub power_w: f64,
    /// Standard deviation of the power readings within the sample.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub power_std_w: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cpu_power_w: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub gpu_power_w: Option<f64>,
}

/// A mistake in a profile's text: what is wrong and where (byte range into the text).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{message}")]
pub struct ProfileError {
    pub message: String,
    /// Byte range of the offending key, value or cell; `None` when nothing in the text is to
    /// blame (a missing table, an empty file).
    pub span: Option<Range<usize>>,
    /// The TOML library's error behind the message, where there is one.
    #[source]
    cause: Option<TomlError>,
}

/// The TOML library's error behind a [`ProfileError`] (boxed: it is large, and every
/// `Result` of this module would carry the room for it).
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum TomlError {
    #[error(transparent)]
    Read(Box<toml::de::Error>),
    #[error(transparent)]
    Write(Box<toml::ser::Error>),
}

impl ProfileError {
    fn new(message: impl Into<String>, span: Option<Range<usize>>) -> Self {
        Self {
            message: message.into(),
            span,
            cause: None,
        }
    }

    /// A TOML syntax or type error, located where the TOML library locates it.
    fn read(error: toml::de::Error) -> Self {
        Self {
            message: error.message().to_string(),
            span: error.span(),
            cause: Some(TomlError::Read(Box::new(error))),
        }
    }

    fn write(error: toml::ser::Error) -> Self {
        Self {
            message: format!("cannot write profile: {error}"),
            span: None,
            cause: Some(TomlError::Write(Box::new(error))),
        }
    }

    fn at(message: impl Into<String>, span: Range<usize>) -> Self {
        Self::new(message, Some(span))
    }

    /// 1-based line and column (in characters) of the start of the span in `text`.
    pub fn line_col(&self, text: &str) -> Option<(usize, usize)> {
        self.span.as_ref().map(|s| line_col(text, s.start))
    }
}

/// 1-based line and column (in characters) of byte `offset` in `text`; an offset past the end
/// or inside a character points at the next character boundary's position.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut end = offset.min(text.len());
    while !text.is_char_boundary(end) {
        end -= 1;
    }
    let before = &text[..end];
    let line = before.matches('\n').count() + 1;
    let line_start = before.rfind('\n').map_or(0, |i| i + 1);
    let col = before[line_start..].chars().count() + 1;
    (line, col)
}

// ---------------------------------------------------------------------------------------------
// Shared validation

/// `task.knob`: two non-empty parts of ASCII letters, digits, `_` or `-`, joined by one dot.
fn check_knob_name(name: &str) -> Result<(), String> {
    let part_ok = |p: &str| {
        !p.is_empty()
            && p.chars()
                .all(|c| c.is_ascii_alphanumeric() || "_-".contains(c))
    };
    match name.split_once('.') {
        Some((task, knob)) if part_ok(task) && part_ok(knob) => Ok(()),
        _ => Err(format!(
            "knob name `{name}` must be `task.knob` (letters, digits, `_`, `-`), e.g. `detection.rate_fps`"
        )),
    }
}

fn check_positive(what: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(format!("{what} must be a finite number > 0, got {v}"))
    }
}

fn check_non_negative(what: &str, v: f64) -> Result<(), String> {
    if v.is_finite() && v >= 0.0 {
        Ok(())
    } else {
        Err(format!("{what} must be a finite number >= 0, got {v}"))
    }
}

/// Index of the first earlier sample with the same knob point, if any. Compared exactly: the
/// values are typed-in operating points, not computed ones.
fn earlier_duplicate(samples: &[Sample], i: usize) -> Option<usize> {
    samples[..i]
        .iter()
        .position(|s| s.knobs == samples[i].knobs)
}

// ---------------------------------------------------------------------------------------------
// TOML

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawProfile {
    board: Spanned<String>,
    meter: Spanned<String>,
    #[serde(default)]
    sample_rate_hz: Option<Spanned<f64>>,
    #[serde(default)]
    source: Option<String>,
    #[serde(default)]
    idle_power_w: Option<Spanned<f64>>,
    #[serde(default)]
    idle_power_std_w: Option<Spanned<f64>>,
    knobs: Spanned<Vec<Spanned<String>>>,
    #[serde(default)]
    sample: Vec<RawSample>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawSample {
    knobs: Spanned<Vec<Spanned<f64>>>,
    power_w: Spanned<f64>,
    #[serde(default)]
    power_std_w: Option<Spanned<f64>>,
    #[serde(default)]
    duration_s: Option<Spanned<f64>>,
    #[serde(default)]
    cpu_power_w: Option<Spanned<f64>>,
    #[serde(default)]
    gpu_power_w: Option<Spanned<f64>>,
}

/// Checks an optional spanned value and unwraps it.
fn opt_checked(
    v: Option<Spanned<f64>>,
    check: impl Fn(f64) -> Result<(), String>,
) -> Result<Option<f64>, ProfileError> {
    match v {
        None => Ok(None),
        Some(s) => {
            check(*s.get_ref()).map_err(|m| ProfileError::at(m, s.span()))?;
            Ok(Some(s.into_inner()))
        }
    }
}

impl Profile {
    /// Parses and validates the project's TOML profile format.
    ///
    /// ```toml
    /// board = "jetson-nano"
    /// meter = "INA3221"
    /// sample_rate_hz = 10.0          # optional
    /// source = "where the figures come from"   # optional
    /// idle_power_w = 1.9             # optional: no task running; and idle_power_std_w
    /// knobs = ["hazard.rate_fps", "detection.rate_fps"]
    ///
    /// [[sample]]
    /// knobs = [4.0, 10.0]            # in the order of `knobs`
    /// power_w = 6.22922
    /// power_std_w = 1.446            # optional, as are duration_s, cpu_power_w, gpu_power_w
    /// ```
    pub fn from_toml_str(text: &str) -> Result<Profile, ProfileError> {
        let raw: RawProfile = toml::from_str(text).map_err(ProfileError::read)?;

        let board_span = raw.board.span();
        let board = raw.board.into_inner();
        if board.trim().is_empty() {
            return Err(ProfileError::at("`board` must not be empty", board_span));
        }
        let meter_span = raw.meter.span();
        let meter = raw.meter.into_inner();
        if meter.trim().is_empty() {
            return Err(ProfileError::at("`meter` must not be empty", meter_span));
        }
        let sample_rate_hz =
            opt_checked(raw.sample_rate_hz, |v| check_positive("sample_rate_hz", v))?;
        let idle_power_w = opt_checked(raw.idle_power_w, |v| check_positive("idle_power_w", v))?;
        let idle_power_std_w = opt_checked(raw.idle_power_std_w, |v| {
            check_non_negative("idle_power_std_w", v)
        })?;

        let knobs_span = raw.knobs.span();
        let mut knobs: Vec<String> = Vec::new();
        for name in raw.knobs.into_inner() {
            let span = name.span();
            let name = name.into_inner();
            check_knob_name(&name).map_err(|m| ProfileError::at(m, span.clone()))?;
            if knobs.contains(&name) {
                return Err(ProfileError::at(
                    format!("knob `{name}` is listed twice"),
                    span,
                ));
            }
            knobs.push(name);
        }

        if raw.sample.is_empty() {
            return Err(ProfileError::new(
                "a profile needs at least one `[[sample]]` table",
                Some(knobs_span),
            ));
        }

        let mut samples: Vec<Sample> = Vec::with_capacity(raw.sample.len());
        for (i, rs) in raw.sample.into_iter().enumerate() {
            let n = i + 1;
            let kspan = rs.knobs.span();
            let values = rs.knobs.into_inner();
            if values.len() != knobs.len() {
                return Err(ProfileError::at(
                    format!(
                        "sample {n}: {} knob values for {} knobs ({})",
                        values.len(),
                        knobs.len(),
                        knobs.join(", ")
                    ),
                    kspan,
                ));
            }
            let mut point = Vec::with_capacity(values.len());
            for (v, name) in values.into_iter().zip(&knobs) {
                if !v.get_ref().is_finite() {
                    return Err(ProfileError::at(
                        format!(
                            "sample {n}: value of `{name}` must be finite, got {}",
                            v.get_ref()
                        ),
                        v.span(),
                    ));
                }
                point.push(v.into_inner());
            }
            let pspan = rs.power_w.span();
            let power_w = rs.power_w.into_inner();
            check_positive("power_w", power_w)
                .map_err(|m| ProfileError::at(format!("sample {n}: {m}"), pspan))?;
            let with_n =
                |e: ProfileError| ProfileError::new(format!("sample {n}: {}", e.message), e.span);
            let sample = Sample {
                knobs: point,
                power_w,
                power_std_w: opt_checked(rs.power_std_w, |v| check_non_negative("power_std_w", v))
                    .map_err(with_n)?,
                duration_s: opt_checked(rs.duration_s, |v| check_positive("duration_s", v))
                    .map_err(with_n)?,
                cpu_power_w: opt_checked(rs.cpu_power_w, |v| check_non_negative("cpu_power_w", v))
                    .map_err(with_n)?,
                gpu_power_w: opt_checked(rs.gpu_power_w, |v| check_non_negative("gpu_power_w", v))
                    .map_err(with_n)?,
            };
            samples.push(sample);
            if let Some(j) = earlier_duplicate(&samples, i) {
                return Err(ProfileError::at(
                    format!(
                        "sample {n} repeats the knob point {:?} of sample {}",
                        samples[i].knobs,
                        j + 1
                    ),
                    kspan,
                ));
            }
        }

        Ok(Profile {
            board,
            meter,
            sample_rate_hz,
            source: raw.source,
            idle_power_w,
            idle_power_std_w,
            knobs,
            samples,
        })
    }

    /// Writes the profile in the format [`Profile::from_toml_str`] reads.
    pub fn to_toml_string(&self) -> Result<String, ProfileError> {
        toml::to_string(self).map_err(ProfileError::write)
    }

    /// `(knob point, power_w)` of every sample, the input of a grid model.
    pub fn power_points(&self) -> Vec<(Vec<f64>, f64)> {
        self.samples
            .iter()
            .map(|s| (s.knobs.clone(), s.power_w))
            .collect()
    }
}

#[cfg(test)]
mod tests;
