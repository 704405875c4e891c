//! powprofiler's CSV: its grid files read into a [`Profile`] and written from one, and its
//! power traces summarised into samples.

use std::ops::Range;

use serde::Serialize;

use super::{
    check_knob_name, check_non_negative, check_positive, earlier_duplicate, line_col, Profile,
    ProfileError, Sample,
};

/// powprofiler's usual sampling rate, and the rate of the seed's Jetson Nano files.
pub const POWPROFILER_DEFAULT_RATE_HZ: f64 = 10.0;

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
