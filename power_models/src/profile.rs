//! Measured power profiles: QoS knob values → mean power, with the board, meter and spread.
//!
//! Two readers: the project's own TOML format ([`Profile::from_toml_str`]) and powprofiler's
//! CSV ([`Profile::from_powprofiler_csv`], [`PowprofilerCsv`], [`summarise_trace`]). Both take
//! the text, never a path, and report mistakes as a [`ProfileError`] with the byte span of the
//! offending key, value or cell, so a caller can print `FILE:LINE:COL` with [`line_col`].

use std::ops::Range;

use serde::{Deserialize, Serialize};
use toml::Spanned;

/// powprofiler's usual sampling rate, and the rate of the seed's Jetson Nano files.
pub const POWPROFILER_DEFAULT_RATE_HZ: f64 = 10.0;

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
}

impl ProfileError {
    fn new(message: impl Into<String>, span: Option<Range<usize>>) -> Self {
        Self {
            message: message.into(),
            span,
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
        let raw: RawProfile = toml::from_str(text)
            .map_err(|e| ProfileError::new(e.message().to_string(), e.span()))?;

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
        toml::to_string(self)
            .map_err(|e| ProfileError::new(format!("cannot write profile: {e}"), None))
    }

    /// `(knob point, power_w)` of every sample, the input of a grid model.
    pub fn power_points(&self) -> Vec<(Vec<f64>, f64)> {
        self.samples
            .iter()
            .map(|s| (s.knobs.clone(), s.power_w))
            .collect()
    }
}

// ---------------------------------------------------------------------------------------------
// powprofiler CSV

/// Which measurement a powprofiler column carries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum Channel {
    Total,
    Cpu,
    Gpu,
}

/// One powprofiler column flag.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub enum PowFlag {
    /// 200 + i: the (i+1)-th QoS knob.
    Knob(usize),
    /// 100/101/102: power in W.
    Power(Channel),
    /// 130/131/132: "energy"; in the seed's files the plain sum of the samples.
    Energy(Channel),
    /// 160/161/162: state of charge.
    StateOfCharge(Channel),
}

impl PowFlag {
    fn from_code(code: u32) -> Option<PowFlag> {
        let channel = |c: u32| match c {
            0 => Some(Channel::Total),
            1 => Some(Channel::Cpu),
            2 => Some(Channel::Gpu),
            _ => None,
        };
        match code {
            100..=102 => channel(code - 100).map(PowFlag::Power),
            130..=132 => channel(code - 130).map(PowFlag::Energy),
            160..=162 => channel(code - 160).map(PowFlag::StateOfCharge),
            200..=299 => Some(PowFlag::Knob((code - 200) as usize)),
            _ => None,
        }
    }
}

/// A parsed powprofiler CSV: a flag row, then rows of numbers. Both grids (one row per knob
/// point) and raw traces (one row per meter sample) have this shape.
#[derive(Debug, Clone, PartialEq)]
pub struct PowprofilerCsv {
    /// Flags of each column (a header cell may join several with `+`).
    pub columns: Vec<Vec<PowFlag>>,
    pub rows: Vec<Vec<f64>>,
    /// Byte span of each row in the text, for error messages.
    pub row_spans: Vec<Range<usize>>,
    /// Byte span of each header cell.
    pub header_spans: Vec<Range<usize>>,
}

/// Lines of `text` with their byte offsets, without line terminators.
fn lines_with_offsets(text: &str) -> impl Iterator<Item = (usize, &str)> {
    let mut offset = 0;
    text.split_inclusive('\n').map(move |raw| {
        let start = offset;
        offset += raw.len();
        let line = raw.strip_suffix('\n').unwrap_or(raw);
        (start, line.strip_suffix('\r').unwrap_or(line))
    })
}

/// Cells of a line with their byte spans (trimmed).
fn cells(line: &str, start: usize, delimiter: char) -> Vec<(Range<usize>, &str)> {
    let mut out = Vec::new();
    let mut pos = 0;
    for cell in line.split(delimiter) {
        let lead = cell.len() - cell.trim_start().len();
        let trimmed = cell.trim();
        let s = start + pos + lead;
        out.push((s..s + trimmed.len(), trimmed));
        pos += cell.len() + delimiter.len_utf8();
    }
    out
}

impl PowprofilerCsv {
    /// Parses the flag row and the numeric rows. Cells are separated by commas, or by tabs as
    /// powprofiler itself writes them; blank lines are skipped.
    pub fn parse(text: &str) -> Result<PowprofilerCsv, ProfileError> {
        let text_body = text.strip_prefix('\u{feff}').unwrap_or(text);
        let bom = text.len() - text_body.len();
        let mut lines = lines_with_offsets(text_body)
            .map(|(o, l)| (o + bom, l))
            .filter(|(_, l)| !l.trim().is_empty());
        let Some((hstart, header)) = lines.next() else {
            return Err(ProfileError::new(
                "empty CSV: expected a first row of powprofiler flags (100 = power, 200 = first knob, …)",
                None,
            ));
        };
        let delimiter = if !header.contains(',') && header.contains('\t') {
            '\t'
        } else {
            ','
        };

        let mut columns = Vec::new();
        let mut header_spans = Vec::new();
        let mut seen: Vec<(PowFlag, usize)> = Vec::new();
        for (c, (span, cell)) in cells(header, hstart, delimiter).into_iter().enumerate() {
            let col = c + 1;
            let mut flags = Vec::new();
            for part in cell.split('+') {
                let part = part.trim();
                let flag = part
                    .parse::<u32>()
                    .ok()
                    .and_then(PowFlag::from_code)
                    .ok_or_else(|| {
                        ProfileError::at(
                            format!(
                                "column {col}: unknown powprofiler flag `{part}` (expected 100–102 power, \
                                 130–132 energy, 160–162 state of charge, 200–299 QoS knobs, joined by `+`)"
                            ),
                            span.clone(),
                        )
                    })?;
                if let Some(&(_, other)) = seen.iter().find(|(f, _)| *f == flag) {
                    return Err(ProfileError::at(
                        format!("column {col}: flag `{part}` is already given to column {other}"),
                        span,
                    ));
                }
                seen.push((flag, col));
                flags.push(flag);
            }
            columns.push(flags);
            header_spans.push(span);
        }

        // Knob flags must be 200, 201, … without gaps, so knob i is the i-th name given.
        let knob_count = seen
            .iter()
            .filter(|(f, _)| matches!(f, PowFlag::Knob(_)))
            .count();
        if let Some(&(PowFlag::Knob(k), col)) = seen
            .iter()
            .find(|(f, _)| matches!(f, PowFlag::Knob(k) if *k >= knob_count))
        {
            return Err(ProfileError::at(
                format!(
                    "column {col}: knob flag {} without all of 200..{} before it",
                    200 + k,
                    200 + k
                ),
                header_spans[col - 1].clone(),
            ));
        }

        let mut rows = Vec::new();
        let mut row_spans = Vec::new();
        for (start, line) in lines {
            let (row_line, _) = line_col(text, start);
            let row_cells = cells(line, start, delimiter);
            if row_cells.len() != columns.len() {
                return Err(ProfileError::at(
                    format!(
                        "line {row_line}: {} cells, but the flag row has {} columns",
                        row_cells.len(),
                        columns.len()
                    ),
                    start..start + line.len(),
                ));
            }
            let mut row = Vec::with_capacity(row_cells.len());
            for (c, (span, cell)) in row_cells.into_iter().enumerate() {
                let v: f64 = cell.parse().map_err(|_| {
                    ProfileError::at(
                        format!(
                            "line {row_line}, column {}: `{cell}` is not a number",
                            c + 1
                        ),
                        span.clone(),
                    )
                })?;
                if !v.is_finite() {
                    return Err(ProfileError::at(
                        format!("line {row_line}, column {}: `{cell}` is not finite", c + 1),
                        span,
                    ));
                }
                row.push(v);
            }
            rows.push(row);
            row_spans.push(start..start + line.len());
        }
        Ok(PowprofilerCsv {
            columns,
            rows,
            row_spans,
            header_spans,
        })
    }

    /// Index of the column carrying `flag`.
    pub fn column(&self, flag: PowFlag) -> Option<usize> {
        self.columns.iter().position(|fs| fs.contains(&flag))
    }

    /// Number of QoS knob columns (flags 200, 201, …).
    pub fn knob_count(&self) -> usize {
        self.columns
            .iter()
            .flatten()
            .filter(|f| matches!(f, PowFlag::Knob(_)))
            .count()
    }
}

impl Profile {
    /// Reads a powprofiler grid CSV sampled at [`POWPROFILER_DEFAULT_RATE_HZ`] (10 Hz, as the
    /// seed's files). See [`Profile::from_powprofiler_csv_with_rate`].
    pub fn from_powprofiler_csv(text: &str, knob_names: &[&str]) -> Result<Profile, ProfileError> {
        Self::from_powprofiler_csv_with_rate(text, knob_names, POWPROFILER_DEFAULT_RATE_HZ)
    }

    /// Reads a powprofiler grid CSV: one row per knob point; column 100 is the sample's power,
    /// 101/102 its CPU/GPU power, and column 130 the sum of its meter readings, so
    /// `130 / 100` readings were taken and `duration_s = readings / sample_rate_hz`.
    /// `knob_names[i]` names flag `200 + i`. The board and meter are not in the file: they are
    /// set to `"unknown"` and `"powprofiler"` for the caller to overwrite.
    pub fn from_powprofiler_csv_with_rate(
        text: &str,
        knob_names: &[&str],
        sample_rate_hz: f64,
    ) -> Result<Profile, ProfileError> {
        check_positive("sample_rate_hz", sample_rate_hz).map_err(|m| ProfileError::new(m, None))?;
        for name in knob_names {
            check_knob_name(name).map_err(|m| ProfileError::new(m, None))?;
        }
        if let Some((i, name)) = knob_names
            .iter()
            .enumerate()
            .find(|(i, n)| knob_names[..*i].contains(n))
        {
            return Err(ProfileError::new(
                format!("knob `{name}` is named twice (position {})", i + 1),
                None,
            ));
        }
        let csv = PowprofilerCsv::parse(text)?;
        let header_span = || {
            let first = csv.header_spans.first().map_or(0, |s| s.start);
            let last = csv.header_spans.last().map_or(0, |s| s.end);
            Some(first..last)
        };
        let knob_count = csv.knob_count();
        if knob_count == 0 && csv.rows.len() > 1 {
            return Err(ProfileError::new(
                "no QoS knob columns (flags 200, 201, …): this looks like a raw trace; \
                 summarise it with `summarise_trace`",
                header_span(),
            ));
        }
        if knob_count != knob_names.len() {
            return Err(ProfileError::new(
                format!(
                    "the CSV has {knob_count} knob columns but {} knob names were given",
                    knob_names.len()
                ),
                header_span(),
            ));
        }
        let Some(power_col) = csv.column(PowFlag::Power(Channel::Total)) else {
            return Err(ProfileError::new(
                "no total power column (flag 100)",
                header_span(),
            ));
        };
        if csv.rows.is_empty() {
            return Err(ProfileError::new(
                "the CSV has a flag row but no samples",
                header_span(),
            ));
        }
        let knob_cols: Vec<usize> = (0..knob_count)
            .map(|k| csv.column(PowFlag::Knob(k)).unwrap_or(0))
            .collect();
        let cpu_col = csv.column(PowFlag::Power(Channel::Cpu));
        let gpu_col = csv.column(PowFlag::Power(Channel::Gpu));
        let energy_col = csv.column(PowFlag::Energy(Channel::Total));

        let mut samples: Vec<Sample> = Vec::with_capacity(csv.rows.len());
        for (i, (row, span)) in csv.rows.iter().zip(&csv.row_spans).enumerate() {
            let (line, _) = line_col(text, span.start);
            let err = |m: String| ProfileError::at(format!("line {line}: {m}"), span.clone());
            let power_w = row[power_col];
            check_positive("power (column 100)", power_w).map_err(err)?;
            let opt = |col: Option<usize>, what: &str| -> Result<Option<f64>, ProfileError> {
                col.map(|c| {
                    check_non_negative(what, row[c]).map_err(err)?;
                    Ok(row[c])
                })
                .transpose()
            };
            let cpu_power_w = opt(cpu_col, "CPU power (column 101)")?;
            let gpu_power_w = opt(gpu_col, "GPU power (column 102)")?;
            let duration_s = match energy_col {
                None => None,
                Some(c) => {
                    check_positive("energy (column 130)", row[c]).map_err(err)?;
                    // The energy is a sum of readings, printed to 6 digits like the power: the
                    // ratio is a whole number of readings up to rounding.
                    let readings = (row[c] / power_w).round();
                    Some(readings.max(1.0) / sample_rate_hz)
                }
            };
            samples.push(Sample {
                knobs: knob_cols.iter().map(|&c| row[c]).collect(),
                power_w,
                power_std_w: None,
                duration_s,
                cpu_power_w,
                gpu_power_w,
            });
            if let Some(j) = earlier_duplicate(&samples, i) {
                let (first_line, _) = line_col(text, csv.row_spans[j].start);
                return Err(err(format!(
                    "knob point {:?} repeats line {first_line}",
                    samples[i].knobs
                )));
            }
        }
        Ok(Profile {
            board: "unknown".to_string(),
            meter: "powprofiler".to_string(),
            sample_rate_hz: Some(sample_rate_hz),
            source: None,
            idle_power_w: None,
            idle_power_std_w: None,
            knobs: knob_names.iter().map(|s| s.to_string()).collect(),
            samples,
        })
    }
}

/// Mean and spread of one channel of a raw trace.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct ChannelStats {
    pub mean_w: f64,
    /// Sample standard deviation (divides by n − 1).
    pub std_w: f64,
}

/// Summary of a raw powprofiler trace (one row per meter reading).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct TraceSummary {
    pub readings: usize,
    pub duration_s: f64,
    pub total: ChannelStats,
    pub cpu: Option<ChannelStats>,
    pub gpu: Option<ChannelStats>,
}

impl TraceSummary {
    /// The trace as one profile sample at the given knob point.
    pub fn to_sample(&self, knobs: Vec<f64>) -> Sample {
        Sample {
            knobs,
            power_w: self.total.mean_w,
            power_std_w: Some(self.total.std_w),
            duration_s: Some(self.duration_s),
            cpu_power_w: self.cpu.map(|c| c.mean_w),
            gpu_power_w: self.gpu.map(|c| c.mean_w),
        }
    }
}

fn channel_stats(values: impl Iterator<Item = f64> + Clone, n: usize) -> ChannelStats {
    // Two passes: the mean first, then squared deviations, which keeps the variance accurate
    // when the spread is small next to the mean.
    let mean_w = values.clone().sum::<f64>() / n as f64;
    let ss: f64 = values.map(|v| (v - mean_w) * (v - mean_w)).sum();
    ChannelStats {
        mean_w,
        std_w: (ss / (n as f64 - 1.0)).sqrt(),
    }
}

impl ChannelStats {
    /// Mean and sample standard deviation of `values_w`; `None` below 2 values, where a
    /// spread means nothing.
    pub fn of(values_w: &[f64]) -> Option<ChannelStats> {
        (values_w.len() >= 2).then(|| channel_stats(values_w.iter().copied(), values_w.len()))
    }
}

impl Profile {
    /// The profile as a powprofiler grid CSV, for exchange: knob columns `200, 201, …`, then
    /// `100` (power), `101`/`102` (CPU/GPU power) where every sample has them, and `130` where
    /// every sample has a duration. Column 130 is what powprofiler and the seed's files put
    /// there, the plain sum of the readings: `power_w × duration_s × sample_rate_hz`, so that
    /// [`Profile::from_powprofiler_csv_with_rate`] at this profile's rate (powprofiler's 10 Hz
    /// when it has none) gives the durations back. Board, meter, source, spread and idle power
    /// have no column and are left out.
    pub fn to_powprofiler_csv(&self) -> String {
        let rate_hz = self.sample_rate_hz.unwrap_or(POWPROFILER_DEFAULT_RATE_HZ);
        let all = |f: fn(&Sample) -> bool| !self.samples.is_empty() && self.samples.iter().all(f);
        let with_cpu = all(|s| s.cpu_power_w.is_some());
        let with_gpu = all(|s| s.gpu_power_w.is_some());
        let with_energy = all(|s| s.duration_s.is_some());
        let mut header: Vec<String> = (0..self.knobs.len())
            .map(|i| (200 + i).to_string())
            .collect();
        header.push("100".into());
        for (flag, on) in [("101", with_cpu), ("102", with_gpu), ("130", with_energy)] {
            if on {
                header.push(flag.into());
            }
        }
        let mut out = header.join(",");
        out.push('\n');
        for s in &self.samples {
            let mut row: Vec<String> = s.knobs.iter().map(|v| v.to_string()).collect();
            row.push(s.power_w.to_string());
            if with_cpu {
                row.push(s.cpu_power_w.unwrap_or_default().to_string());
            }
            if with_gpu {
                row.push(s.gpu_power_w.unwrap_or_default().to_string());
            }
            if with_energy {
                let readings = (s.duration_s.unwrap_or_default() * rate_hz).round();
                row.push((s.power_w * readings).to_string());
            }
            out.push_str(&row.join(","));
            out.push('\n');
        }
        out
    }
}

/// Mean, spread and duration of a raw powprofiler trace: columns 100 (required), 101 and 102,
/// one row per reading taken at `sample_rate_hz`.
pub fn summarise_trace(text: &str, sample_rate_hz: f64) -> Result<TraceSummary, ProfileError> {
    check_positive("sample_rate_hz", sample_rate_hz).map_err(|m| ProfileError::new(m, None))?;
    let csv = PowprofilerCsv::parse(text)?;
    for (flags, span) in csv.columns.iter().zip(&csv.header_spans) {
        if !flags.iter().all(|f| matches!(f, PowFlag::Power(_))) {
            return Err(ProfileError::at(
                "a raw trace holds only power columns (100, 101, 102); this looks like a grid, \
                 read it with `Profile::from_powprofiler_csv`",
                span.clone(),
            ));
        }
    }
    let Some(total_col) = csv.column(PowFlag::Power(Channel::Total)) else {
        return Err(ProfileError::new("no total power column (flag 100)", None));
    };
    let n = csv.rows.len();
    if n < 2 {
        return Err(ProfileError::new(
            format!("a trace needs at least 2 readings for a spread, got {n}"),
            None,
        ));
    }
    let stats = |c: usize| channel_stats(csv.rows.iter().map(move |r| r[c]), n);
    Ok(TraceSummary {
        readings: n,
        duration_s: n as f64 / sample_rate_hz,
        total: stats(total_col),
        cpu: csv.column(PowFlag::Power(Channel::Cpu)).map(stats),
        gpu: csv.column(PowFlag::Power(Channel::Gpu)).map(stats),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    /// `../shared/data/<sub>` next to the workspace root, or `None` (and a note) when absent.
    fn shared_data(sub: &str) -> Option<PathBuf> {
        let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data")
            .join(sub);
        if dir.is_dir() {
            Some(dir)
        } else {
            eprintln!(
                "SKIP: {} is absent, the test needs the shared seed data",
                dir.display()
            );
            None
        }
    }

    fn read(dir: &std::path::Path, file: &str) -> String {
        std::fs::read_to_string(dir.join(file)).expect("readable data file")
    }

    fn shipped(file: &str) -> String {
        let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../profiles/jetson-nano-seed")
            .join(file);
        std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
    }

    const GOOD: &str = r#"board = "jetson-nano"
meter = "INA3221"
sample_rate_hz = 10
source = "hand-written test"
knobs = ["hazard.rate_fps", "detection.rate_fps"]

[[sample]]
knobs = [4, 10.0]
power_w = 6.5
power_std_w = 1.25
duration_s = 100.0
cpu_power_w = 2.0
gpu_power_w = 1.5

[[sample]]
knobs = [1.0, 0.5]
power_w = 4
"#;

    #[test]
    fn toml_reads_every_field() {
        let p = Profile::from_toml_str(GOOD).unwrap();
        assert_eq!(p.board, "jetson-nano");
        assert_eq!(p.meter, "INA3221");
        assert_eq!(p.sample_rate_hz, Some(10.0));
        assert_eq!(p.source.as_deref(), Some("hand-written test"));
        assert_eq!(p.knobs, ["hazard.rate_fps", "detection.rate_fps"]);
        assert_eq!(
            p.samples[0],
            Sample {
                knobs: vec![4.0, 10.0],
                power_w: 6.5,
                power_std_w: Some(1.25),
                duration_s: Some(100.0),
                cpu_power_w: Some(2.0),
                gpu_power_w: Some(1.5),
            }
        );
        // Integers are accepted where a float is expected, and omitted options stay None.
        assert_eq!(
            p.samples[1],
            Sample {
                knobs: vec![1.0, 0.5],
                power_w: 4.0,
                power_std_w: None,
                duration_s: None,
                cpu_power_w: None,
                gpu_power_w: None,
            }
        );
    }

    #[test]
    fn toml_round_trips() {
        let p = Profile::from_toml_str(GOOD).unwrap();
        let text = p.to_toml_string().unwrap();
        assert_eq!(Profile::from_toml_str(&text).unwrap(), p);
        // A profile with awkward floats round-trips too.
        let mut q = p.clone();
        q.samples[1].power_w = 0.1 + 0.2;
        q.samples[1].knobs = vec![1.0 / 3.0, 1e-7];
        q.source = None;
        let text = q.to_toml_string().unwrap();
        assert_eq!(Profile::from_toml_str(&text).unwrap(), q);
    }

    /// Parses `text`, expects an error whose message contains `needle` and whose span covers
    /// exactly `at` in the text.
    fn expect_err(text: &str, needle: &str, at: &str) {
        let err = Profile::from_toml_str(text).expect_err("bad profile accepted");
        assert!(
            err.message.contains(needle),
            "message `{}` lacks `{needle}`",
            err.message
        );
        let span = err.span.clone().expect("error has a span");
        assert_eq!(&text[span], at, "span of `{}`", err.message);
    }

    #[test]
    fn toml_errors_point_at_the_offending_text() {
        expect_err(
            &GOOD.replace("power_w = 4\n", "power_w = -4\n"),
            "power_w",
            "-4",
        );
        expect_err(&GOOD.replace("power_w = 4\n", "power_w = 0\n"), "> 0", "0");
        expect_err(
            &GOOD.replace("knobs = [1.0, 0.5]", "knobs = [1.0]"),
            "1 knob values for 2 knobs",
            "[1.0]",
        );
        expect_err(
            &GOOD.replace("knobs = [1.0, 0.5]", "knobs = [nan, 0.5]"),
            "finite",
            "nan",
        );
        expect_err(
            &GOOD.replace("knobs = [1.0, 0.5]", "knobs = [4.0, 10]"),
            "repeats",
            "[4.0, 10]",
        );
        expect_err(
            &GOOD.replace("\"hazard.rate_fps\"", "\"hazard\""),
            "task.knob",
            "\"hazard\"",
        );
        expect_err(
            &GOOD.replace("\"hazard.rate_fps\"", "\"detection.rate_fps\""),
            "twice",
            "\"detection.rate_fps\"",
        );
        expect_err(
            &GOOD.replace("power_std_w", "power_sd_w"),
            "unknown field",
            "power_sd_w",
        );
        expect_err(
            &GOOD.replace("meter = \"INA3221\"", "meter = 3"),
            "invalid type",
            "3",
        );
        expect_err(
            &GOOD.replace("sample_rate_hz = 10", "sample_rate_hz = 0"),
            "sample_rate_hz",
            "0",
        );
        expect_err(
            &GOOD.replace("duration_s = 100.0", "duration_s = -1.0"),
            "duration_s",
            "-1.0",
        );
        expect_err(
            &GOOD.replace("board = \"jetson-nano\"", "board = \" \""),
            "board",
            "\" \"",
        );
        expect_err(
            &GOOD.replace("gpu_power_w = 1.5", "gpu_power_w = inf"),
            "gpu_power_w",
            "inf",
        );
    }

    #[test]
    fn toml_errors_without_a_value_to_blame() {
        let no_samples = "board = \"b\"\nmeter = \"m\"\nknobs = [\"a.b\"]\n";
        let err = Profile::from_toml_str(no_samples).unwrap_err();
        assert!(err.message.contains("at least one"), "{}", err.message);
        let missing_board = GOOD.replace("board = \"jetson-nano\"\n", "");
        let err = Profile::from_toml_str(&missing_board).unwrap_err();
        assert!(err.message.contains("board"), "{}", err.message);
        let broken = GOOD.replace("power_w = 4\n", "power_w = \n");
        let err = Profile::from_toml_str(&broken).unwrap_err();
        let (line, _) = err.line_col(&broken).expect("syntax error has a position");
        assert_eq!(line, 17, "{err:?}");
    }

    #[test]
    fn line_col_counts_lines_and_characters() {
        let text = "ab\nçd\n\nx";
        assert_eq!(line_col(text, 0), (1, 1));
        assert_eq!(line_col(text, 1), (1, 2));
        assert_eq!(line_col(text, 3), (2, 1));
        // `ç` is two bytes: `d` is the 2nd character of line 2.
        assert_eq!(line_col(text, 5), (2, 2));
        assert_eq!(line_col(text, 8), (4, 1));
        assert_eq!(line_col(text, 100), (4, 2));
    }

    const GRID_CSV: &str =
        "200,201,100,101,102,130\n4,10,6.0,2.0,1.9,6000\n4,0.5,6.3,2.1,2.0,6237\n";

    #[test]
    fn csv_grid_reads_knobs_power_and_duration() {
        let p = Profile::from_powprofiler_csv(GRID_CSV, &["hazard.rate_fps", "detection.rate_fps"])
            .unwrap();
        assert_eq!(p.knobs, ["hazard.rate_fps", "detection.rate_fps"]);
        assert_eq!(p.sample_rate_hz, Some(10.0));
        assert_eq!(p.samples.len(), 2);
        let s = &p.samples[1];
        assert_eq!(s.knobs, [4.0, 0.5]);
        assert_eq!(s.power_w, 6.3);
        assert_eq!(s.cpu_power_w, Some(2.1));
        assert_eq!(s.gpu_power_w, Some(2.0));
        // 6237 / 6.3 = 990 readings at 10 Hz.
        assert_eq!(s.duration_s, Some(99.0));
        assert_eq!(p.samples[0].duration_s, Some(100.0));
    }

    #[test]
    fn csv_flag_order_joined_flags_and_tabs() {
        // Columns in any order, a cell with two flags, tab-separated, CRLF, trailing blank line.
        let text = "100\t201\t200+160\r\n5.5\t2\t8\r\n\r\n";
        let p = Profile::from_powprofiler_csv(text, &["a.x", "b.y"]).unwrap();
        assert_eq!(p.samples.len(), 1);
        assert_eq!(p.samples[0].knobs, [8.0, 2.0]);
        assert_eq!(p.samples[0].power_w, 5.5);
        assert_eq!(p.samples[0].duration_s, None);
        let csv = PowprofilerCsv::parse(text).unwrap();
        assert_eq!(
            csv.columns[2],
            [PowFlag::Knob(0), PowFlag::StateOfCharge(Channel::Total)]
        );
    }

    fn csv_err(text: &str, knobs: &[&str], needle: &str, at: Option<&str>) {
        let err = Profile::from_powprofiler_csv(text, knobs).expect_err("bad CSV accepted");
        assert!(
            err.message.contains(needle),
            "message `{}` lacks `{needle}`",
            err.message
        );
        match at {
            Some(at) => assert_eq!(
                &text[err.span.clone().expect("span")],
                at,
                "{}",
                err.message
            ),
            None => assert_eq!(err.span, None, "{}", err.message),
        }
    }

    #[test]
    fn csv_bad_input_is_an_error_naming_the_place() {
        let k = &["a.x"];
        csv_err("", k, "empty CSV", None);
        csv_err("\n \n", k, "empty CSV", None);
        csv_err(
            "200,100,150\n1,2,3\n",
            k,
            "column 3: unknown powprofiler flag `150`",
            Some("150"),
        );
        csv_err("200,100,abc\n1,2,3\n", k, "column 3", Some("abc"));
        csv_err(
            "200,100+\n1,2\n",
            k,
            "column 2: unknown powprofiler flag ``",
            Some("100+"),
        );
        csv_err(
            "200,100,100\n1,2,3\n",
            k,
            "already given to column 2",
            Some("100"),
        );
        csv_err("201,100\n1,2\n", k, "without all of 200", Some("201"));
        csv_err(
            "200,100\n1,2\n3,x4\n",
            k,
            "line 3, column 2: `x4` is not a number",
            Some("x4"),
        );
        csv_err("200,100\n1,2\n3\n", k, "line 3: 1 cells", Some("3"));
        csv_err("200,100\n1,2,5\n", k, "line 2: 3 cells", Some("1,2,5"));
        csv_err("200,100\n1,inf\n", k, "not finite", Some("inf"));
        csv_err("200,100\n1,0\n", k, "power (column 100)", Some("1,0"));
        csv_err("200,100\n1,2\n1,3\n", k, "repeats line 2", Some("1,3"));
        csv_err("200,100\n", k, "no samples", Some("200,100"));
        csv_err(
            "200,101\n1,2\n",
            k,
            "no total power column",
            Some("200,101"),
        );
        csv_err(
            "200,100\n1,2\n",
            &["a.x", "b.y"],
            "1 knob columns but 2",
            Some("200,100"),
        );
        csv_err("100,101\n1,2\n3,4\n", &[], "raw trace", Some("100,101"));
        csv_err("200,100\n1,2\n", &["ax"], "task.knob", None);
    }

    #[test]
    fn trace_summary_matches_an_independent_computation() {
        let text = "100,101,102\n3.0,1.0,0.5\n5.0,1.5,0.5\n4.0,2.0,0.5\n6.0,1.5,0.5\n";
        let s = summarise_trace(text, 10.0).unwrap();
        assert_eq!(s.readings, 4);
        assert!((s.duration_s - 0.4).abs() < 1e-12);
        // total: mean 4.5, deviations ±1.5, ±0.5 → sample variance 5/3.
        assert!((s.total.mean_w - 4.5).abs() < 1e-12);
        assert!((s.total.std_w - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        let cpu = s.cpu.unwrap();
        assert!((cpu.mean_w - 1.5).abs() < 1e-12);
        assert!((cpu.std_w - (0.5f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(s.gpu.unwrap().std_w, 0.0);
        let sample = s.to_sample(vec![10.0]);
        assert_eq!(sample.power_w, s.total.mean_w);
        assert_eq!(sample.power_std_w, Some(s.total.std_w));

        assert!(summarise_trace("100\n3\n", 10.0)
            .unwrap_err()
            .message
            .contains("at least 2"));
        assert!(summarise_trace("200,100\n1,3\n2,4\n", 10.0)
            .unwrap_err()
            .message
            .contains("grid"));
        assert!(summarise_trace("101\n1\n2\n", 10.0)
            .unwrap_err()
            .message
            .contains("flag 100"));
        assert!(summarise_trace("100\n1\n2\n", 0.0).is_err());
    }

    /// The seed's rows as `(knobs, [100, 101, 102, 130])`, read by plain splitting.
    fn seed_rows(text: &str, knobs: usize) -> Vec<(Vec<f64>, Vec<f64>)> {
        text.lines()
            .skip(1)
            .filter(|l| !l.trim().is_empty())
            .map(|l| {
                let v: Vec<f64> = l.split(',').map(|c| c.trim().parse().unwrap()).collect();
                (v[..knobs].to_vec(), v[knobs..knobs + 4].to_vec())
            })
            .collect()
    }

    #[test]
    fn seed_csvs_parse() {
        let Some(dir) = shared_data("seed-jetson-nano") else {
            return;
        };
        for (file, names) in [
            (
                "m2l_tracking.csv",
                &["hazard.rate_fps", "detection.rate_fps"][..],
            ),
            ("m2l_landing.csv", &["detection.rate_fps"][..]),
            ("m2l_kernel22.csv", &["detection.rate_fps"][..]),
        ] {
            let text = read(&dir, file);
            let p = Profile::from_powprofiler_csv(&text, names).unwrap();
            let rows = seed_rows(&text, names.len());
            assert_eq!(p.samples.len(), rows.len(), "{file}");
            for (s, (k, v)) in p.samples.iter().zip(&rows) {
                assert_eq!(&s.knobs, k, "{file}");
                assert_eq!(s.power_w, v[0], "{file}");
                assert_eq!(s.cpu_power_w, Some(v[1]), "{file}");
                assert_eq!(s.gpu_power_w, Some(v[2]), "{file}");
                // Several hundred readings a sample, 60–160 s each.
                let d = s.duration_s.unwrap();
                assert!((60.0..160.0).contains(&d), "{file}: {d}");
                assert!((d * 10.0 - v[3] / v[0]).abs() < 0.01, "{file}: {d}");
            }
        }
    }

    #[test]
    fn seed_traces_agree_with_their_grid_rows() {
        let Some(dir) = shared_data("seed-jetson-nano") else {
            return;
        };
        for (trace, grid, knobs) in [
            ("1_Yolo4fps_nfold10fps.csv", "m2l_tracking.csv", 2),
            ("1_nfold10fps.csv", "m2l_landing.csv", 1),
        ] {
            let text = read(&dir, trace);
            let s = summarise_trace(&text, 10.0).unwrap();
            let (_, first) = seed_rows(&read(&dir, grid), knobs)[0].clone();
            // The grid's first row is this trace's mean and its reading count.
            assert!(
                (s.total.mean_w - first[0]).abs() < 1e-5,
                "{trace}: {}",
                s.total.mean_w
            );
            assert!((s.cpu.unwrap().mean_w - first[1]).abs() < 1e-5, "{trace}");
            assert!((s.gpu.unwrap().mean_w - first[2]).abs() < 1e-5, "{trace}");
            assert_eq!(s.readings as f64, (first[3] / first[0]).round(), "{trace}");
            // Independent spread: mean of squares minus square of mean, n/(n−1) corrected.
            let vals: Vec<f64> = text
                .lines()
                .skip(1)
                .map(|l| l.split(',').next().unwrap().parse().unwrap())
                .collect();
            let n = vals.len() as f64;
            let m = vals.iter().sum::<f64>() / n;
            let m2 = vals.iter().map(|v| v * v).sum::<f64>() / n;
            let std = ((m2 - m * m) * n / (n - 1.0)).sqrt();
            assert!(
                (s.total.std_w - std).abs() < 1e-9,
                "{trace}: {} vs {std}",
                s.total.std_w
            );
        }
    }

    #[test]
    fn shipped_seed_profiles_parse_and_equal_the_seed_csvs() {
        let files = [
            (
                "tracking.toml",
                "m2l_tracking.csv",
                "1_Yolo4fps_nfold10fps.csv",
            ),
            ("landing.toml", "m2l_landing.csv", "1_nfold10fps.csv"),
            ("landing-kernel22.toml", "m2l_kernel22.csv", ""),
        ];
        // The shipped files stand alone: they parse and name their source without the data.
        let parsed: Vec<Profile> = files
            .iter()
            .map(|(toml_file, _, _)| {
                let text = shipped(toml_file);
                let p = Profile::from_toml_str(&text).unwrap_or_else(|e| {
                    let (l, c) = e.line_col(&text).unwrap_or((0, 0));
                    panic!("{toml_file}:{l}:{c}: {}", e.message)
                });
                assert_eq!(p.board, "jetson-nano", "{toml_file}");
                assert_eq!(p.meter, "INA3221", "{toml_file}");
                assert_eq!(p.sample_rate_hz, Some(10.0), "{toml_file}");
                assert!(
                    p.source.as_deref().unwrap_or("").contains("seed paper"),
                    "{toml_file}"
                );
                p
            })
            .collect();
        assert_eq!(parsed[0].knobs, ["hazard.rate_fps", "detection.rate_fps"]);
        assert_eq!(parsed[1].knobs, ["detection.rate_fps"]);
        assert_eq!(parsed[2].knobs, ["detection.rate_fps"]);

        let Some(dir) = shared_data("seed-jetson-nano") else {
            return;
        };
        for ((toml_file, csv_file, trace), p) in files.iter().zip(&parsed) {
            let rows = seed_rows(&read(&dir, csv_file), p.knobs.len());
            assert_eq!(p.samples.len(), rows.len(), "{toml_file}");
            for (k, v) in &rows {
                let s = p
                    .samples
                    .iter()
                    .find(|s| &s.knobs == k)
                    .unwrap_or_else(|| panic!("{toml_file} lacks {k:?}"));
                assert_eq!(s.power_w, v[0], "{toml_file} {k:?}");
                assert_eq!(s.cpu_power_w, Some(v[1]), "{toml_file} {k:?}");
                assert_eq!(s.gpu_power_w, Some(v[2]), "{toml_file} {k:?}");
                let readings = (v[3] / v[0]).round();
                assert_eq!(s.duration_s, Some(readings / 10.0), "{toml_file} {k:?}");
            }
            // The first grid row carries the spread of its raw trace, to the digits typed in.
            for (i, s) in p.samples.iter().enumerate() {
                if i == 0 && !trace.is_empty() {
                    let t = summarise_trace(&read(&dir, trace), 10.0).unwrap();
                    let std = s.power_std_w.expect("first row has power_std_w");
                    assert!(
                        (std - t.total.std_w).abs() < 5e-7,
                        "{toml_file}: {std} vs {}",
                        t.total.std_w
                    );
                } else {
                    assert_eq!(s.power_std_w, None, "{toml_file} sample {}", i + 1);
                }
            }
        }
    }

    #[test]
    fn idle_power_reads_round_trips_and_is_checked() {
        let text = GOOD.replace(
            "knobs = [\"hazard",
            "idle_power_w = 1.75\nidle_power_std_w = 0.05\nknobs = [\"hazard",
        );
        let p = Profile::from_toml_str(&text).unwrap();
        assert_eq!(p.idle_power_w, Some(1.75));
        assert_eq!(p.idle_power_std_w, Some(0.05));
        assert_eq!(
            Profile::from_toml_str(&p.to_toml_string().unwrap()).unwrap(),
            p
        );
        expect_err(
            &text.replace("idle_power_w = 1.75", "idle_power_w = 0"),
            "idle_power_w",
            "0",
        );
        expect_err(
            &text.replace("idle_power_std_w = 0.05", "idle_power_std_w = -1.0"),
            "idle_power_std_w",
            "-1.0",
        );
        // Absent, it stays absent in the written text.
        let plain = Profile::from_toml_str(GOOD).unwrap();
        assert_eq!(plain.idle_power_w, None);
        assert!(!plain.to_toml_string().unwrap().contains("idle"));
    }

    #[test]
    fn channel_stats_of_values() {
        // 2, 4, 4, 4, 5, 5, 7, 9: mean 5, squared deviations sum to 32, sample variance 32/7.
        let s = ChannelStats::of(&[2.0, 4.0, 4.0, 4.0, 5.0, 5.0, 7.0, 9.0]).unwrap();
        assert_eq!(s.mean_w, 5.0);
        assert!((s.std_w - (32.0f64 / 7.0).sqrt()).abs() < 1e-12);
        assert_eq!(ChannelStats::of(&[3.0]), None);
        assert_eq!(ChannelStats::of(&[]), None);
    }

    #[test]
    fn powprofiler_csv_written_reads_back() {
        let mut p = Profile::from_toml_str(GOOD).unwrap();
        p.samples[1].duration_s = Some(12.3);
        p.samples[1].cpu_power_w = Some(1.25);
        p.samples[1].gpu_power_w = Some(0.125);
        p.sample_rate_hz = Some(20.0);
        let text = p.to_powprofiler_csv();
        assert_eq!(text.lines().next(), Some("200,201,100,101,102,130"));
        // 130 = power × readings: 6.5 W × (100 s × 20 Hz).
        assert_eq!(text.lines().nth(1), Some("4,10,6.5,2,1.5,13000"));
        let names = ["hazard.rate_fps", "detection.rate_fps"];
        let back = Profile::from_powprofiler_csv_with_rate(&text, &names, 20.0).unwrap();
        assert_eq!(back.knobs, p.knobs);
        for (a, b) in back.samples.iter().zip(&p.samples) {
            assert_eq!(a.knobs, b.knobs);
            assert_eq!(a.power_w, b.power_w);
            assert_eq!(a.cpu_power_w, b.cpu_power_w);
            assert_eq!(a.gpu_power_w, b.gpu_power_w);
            assert!((a.duration_s.unwrap() - b.duration_s.unwrap()).abs() < 1e-9);
        }
        // A sample without CPU power or duration drops those columns for all.
        p.samples[1].cpu_power_w = None;
        p.samples[0].duration_s = None;
        let text = p.to_powprofiler_csv();
        assert_eq!(text.lines().next(), Some("200,201,100,102"));
        let back = Profile::from_powprofiler_csv(&text, &names).unwrap();
        assert_eq!(back.samples[1].power_w, 4.0);
        assert_eq!(back.samples[1].cpu_power_w, None);
    }
}
