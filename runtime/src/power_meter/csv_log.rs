//! An external meter's log (a USB power meter, a bench supply, a logging multimeter): a CSV
//! file that a logger appends to while the sweep runs, one row per reading,
//! `timestamp_s,power_w`, the timestamp in Unix seconds (an optional header row first).
//!
//! Readings are merged by time: each [`PowerMeter::read`] gives the mean of the rows logged
//! since the previous read; when none came (a meter logging slower than the sweep samples), the
//! newest row, as long as it is recent enough. The clocks of the logger and this computer must
//! agree (NTP, or the same machine).

use super::{Clock, MeterError, PowerMeter, PowerReading};
use std::collections::VecDeque;
use std::io::{Read, Seek, SeekFrom};
use std::num::ParseFloatError;
use std::path::{Path, PathBuf};
use std::time::{SystemTime, UNIX_EPOCH};

pub const NAME: &str = "csv";
/// A held reading older than this is an error: the logger has stopped.
pub const DEFAULT_MAX_AGE_S: f64 = 2.0;
/// Readings kept for merging; older ones are dropped.
const KEEP_S: f64 = 60.0;

/// Seconds since the Unix epoch, the log's time scale.
pub fn unix_clock() -> Clock {
    Box::new(|| {
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0.0, |d| d.as_secs_f64())
    })
}

/// Why a line of the log is not a reading.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum LineError {
    #[error("{cells} cells, expected 2: timestamp_s,power_w")]
    Cells { cells: usize },
    #[error("{column} `{text}` is not a finite number ({source})")]
    NotANumber {
        column: &'static str,
        text: String,
        source: ParseFloatError,
    },
    #[error("{column} `{text}` is not a finite number")]
    NotFinite { column: &'static str, text: String },
    #[error("power_w {power_w} is negative")]
    NegativePower { power_w: f64 },
}

/// One data line: `timestamp_s,power_w`. `Ok(None)` for a blank line.
pub fn parse_line(line: &str) -> Result<Option<(f64, f64)>, LineError> {
    let line = line.trim();
    if line.is_empty() {
        return Ok(None);
    }
    let cells: Vec<&str> = line.split(',').map(str::trim).collect();
    if cells.len() != 2 {
        return Err(LineError::Cells { cells: cells.len() });
    }
    let number = |column: &'static str, text: &str| -> Result<f64, LineError> {
        match text.parse::<f64>() {
            Ok(value) if value.is_finite() => Ok(value),
            Ok(_) => Err(LineError::NotFinite {
                column,
                text: text.to_string(),
            }),
            Err(source) => Err(LineError::NotANumber {
                column,
                text: text.to_string(),
                source,
            }),
        }
    };
    let t = number("timestamp_s", cells[0])?;
    let w = number("power_w", cells[1])?;
    if w < 0.0 {
        return Err(LineError::NegativePower { power_w: w });
    }
    Ok(Some((t, w)))
}

/// Mean power of the readings with `after_s < t <= until_s`.
pub fn mean_in_window(readings: &[(f64, f64)], after_s: f64, until_s: f64) -> Option<f64> {
    let (sum, n) = readings
        .iter()
        .filter(|(t, _)| *t > after_s && *t <= until_s)
        .fold((0.0, 0usize), |(s, n), (_, w)| (s + w, n + 1));
    (n > 0).then(|| sum / n as f64)
}

/// A CSV log read as it grows.
pub struct CsvLogMeter {
    path: PathBuf,
    clock: Clock,
    max_age_s: f64,
    /// Bytes of the file consumed so far (complete lines only).
    offset: u64,
    /// Lines consumed so far, for error messages.
    lines: usize,
    readings: VecDeque<(f64, f64)>,
    last_read_s: Option<f64>,
}

impl CsvLogMeter {
    /// Opens the log and reads what it holds so far.
    pub fn open(path: &Path, clock: Clock, max_age_s: f64) -> Result<CsvLogMeter, MeterError> {
        let mut meter = CsvLogMeter {
            path: path.to_path_buf(),
            clock,
            max_age_s,
            offset: 0,
            lines: 0,
            readings: VecDeque::new(),
            last_read_s: None,
        };
        meter.ingest()?;
        Ok(meter)
    }

    /// Reads the complete lines appended since the last call.
    fn ingest(&mut self) -> Result<(), MeterError> {
        let io = |source| MeterError::Io {
            path: self.path.clone(),
            source,
        };
        let mut file = std::fs::File::open(&self.path).map_err(io)?;
        file.seek(SeekFrom::Start(self.offset)).map_err(io)?;
        let mut bytes = Vec::new();
        file.read_to_end(&mut bytes).map_err(io)?;
        // A line still being written has no newline yet: it waits for the next call.
        let complete = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |i| i + 1);
        let text = String::from_utf8_lossy(&bytes[..complete]).into_owned();
        for line in text.lines() {
            self.lines += 1;
            let is_header = self.lines == 1
                && line
                    .trim_start_matches('\u{feff}')
                    .trim()
                    .starts_with(|c: char| c.is_ascii_alphabetic());
            if is_header {
                continue;
            }
            match parse_line(line) {
                Ok(Some(reading)) => self.readings.push_back(reading),
                Ok(None) => {}
                Err(source) => {
                    return Err(MeterError::Csv {
                        path: self.path.clone(),
                        line: self.lines,
                        source,
                    })
                }
            }
        }
        self.offset += complete as u64;
        Ok(())
    }
}

impl PowerMeter for CsvLogMeter {
    fn name(&self) -> &str {
        NAME
    }

    fn describe(&self) -> String {
        format!(
            "external meter's log {} (timestamp_s,power_w; merged by time)",
            self.path.display()
        )
    }

    fn rails(&self) -> Vec<String> {
        vec!["total".to_string()]
    }

    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let now_s = (self.clock)();
        self.ingest()?;
        while self
            .readings
            .front()
            .is_some_and(|(t, _)| *t < now_s - KEEP_S)
        {
            self.readings.pop_front();
        }
        let after_s = self.last_read_s.unwrap_or(now_s - self.max_age_s);
        let readings: Vec<(f64, f64)> = self.readings.iter().copied().collect();
        let power_w = match mean_in_window(&readings, after_s, now_s) {
            Some(power_w) => power_w,
            None => {
                let newest = readings
                    .iter()
                    .filter(|(t, _)| *t <= now_s)
                    .max_by(|a, b| a.0.total_cmp(&b.0));
                match newest {
                    Some(&(t, w)) if now_s - t <= self.max_age_s => w,
                    Some(&(t, _)) => {
                        return Err(MeterError::Stale {
                            path: self.path.clone(),
                            age_s: now_s - t,
                            max_age_s: self.max_age_s,
                        })
                    }
                    None => {
                        return Err(MeterError::CsvNoReading {
                            path: self.path.clone(),
                        })
                    }
                }
            }
        };
        self.last_read_s = Some(now_s);
        Ok(PowerReading {
            total_w: power_w,
            cpu_w: None,
            gpu_w: None,
            rails_w: vec![power_w],
        })
    }
}
