//! Power meters: what `qosrt profile` reads while the tasks run.
//!
//! One trait, [`PowerMeter`], and one implementation per kind of meter a companion computer
//! may have: the Jetson INA3221 in both driver generations ([`ina3221`]), Linux powercap RAPL
//! ([`rapl`]), any hwmon device with power or energy channels ([`hwmon`]), NVIDIA GPUs through
//! NVML loaded at run time ([`nvml`]) and an external meter's CSV log ([`csv_log`]).
//!
//! Every sysfs meter reads below a root path (`/` on a real board), so the tests run them on
//! directory trees laid out like the real sysfs. [`discover`] probes every kind and says, for
//! each place it looked, what it found or why it rejected it: on a machine without a meter
//! that list is the error, never a made-up measurement.

pub mod counter;
pub mod csv_log;
pub mod hwmon;
pub mod ina3221;
pub mod nvml;
pub mod rapl;
mod sysfs;

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One reading of a meter: the board's (or device's) total power and, where the meter has
/// them, its CPU and GPU rails and every rail it reads.
#[derive(Debug, Clone, PartialEq)]
pub struct PowerReading {
    pub total_w: f64,
    pub cpu_w: Option<f64>,
    pub gpu_w: Option<f64>,
    /// Every rail, in the order of [`PowerMeter::rails`].
    pub rails_w: Vec<f64>,
}

/// A power meter.
pub trait PowerMeter {
    /// The meter's kind as `--meter` selects it, e.g. `jetson-ina3221-iio`, `rapl`, `nvml`.
    fn name(&self) -> &str;
    /// What it measures and where it reads, for logs and the profile's `meter` field.
    fn describe(&self) -> String;
    /// Names of the rails it reads, in the order of [`PowerReading::rails_w`].
    fn rails(&self) -> Vec<String>;
    /// Reads the meter now. Energy-counter meters give the mean power since their previous
    /// reading (or since they were opened).
    fn read(&mut self) -> Result<PowerReading, MeterError>;
}

/// Why a meter could not be read.
#[derive(Debug, thiserror::Error)]
pub enum MeterError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}: `{text}` is not {expected}")]
    Garbage {
        path: PathBuf,
        text: String,
        expected: &'static str,
    },
    #[error("{path}: the energy counter went back from {previous_uj} to {now_uj} µJ and no wrap-around range is known (reset?)")]
    CounterBackwards {
        path: PathBuf,
        previous_uj: u64,
        now_uj: u64,
    },
    #[error("{path}: energy counter {now_uj} µJ is above its range {max_uj} µJ")]
    CounterOutOfRange {
        path: PathBuf,
        now_uj: u64,
        max_uj: u64,
    },
    #[error(
        "no time passed since the previous reading of {what}: a counter gives no power over 0 s"
    )]
    NoTimeElapsed { what: String },
    #[error("NVML: {call} failed: {message} (code {code})")]
    Nvml {
        call: &'static str,
        code: u32,
        message: String,
    },
    // libloading's own text is only "dlopen failed"; dlerror()'s (which file, why) is its source.
    #[error(
        "cannot load the library (no NVIDIA driver?): {source}{}",
        std::error::Error::source(source).map_or(String::new(), |detail| format!(": {detail}"))
    )]
    NvmlLoad { source: libloading::Error },
    #[error("the library lacks {symbol}: not NVML?")]
    NvmlSymbol {
        symbol: &'static str,
        source: libloading::Error,
    },
    #[error("NVML sees no GPU")]
    NvmlNoGpu,
    #[error("{path}: a range of 0 µJ")]
    ZeroRange { path: PathBuf },
    #[error(
        "cannot read {path}: {source} (kernels since 2020 let only root read energy_uj: run as \
         root, or `sudo chmod a+r {path}`)"
    )]
    RootOnly {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{path}:{line}: {source}")]
    Csv {
        path: PathBuf,
        line: usize,
        source: csv_log::LineError,
    },
    #[error("{path}: no reading up to now yet (is the logger running, and do the clocks agree?)")]
    CsvNoReading { path: PathBuf },
    #[error("{path}: the newest reading is {age_s:.1} s old (at most {max_age_s:.1} s allowed): is the external meter still logging?")]
    Stale {
        path: PathBuf,
        age_s: f64,
        max_age_s: f64,
    },
}

/// What discovery concluded about one place it looked.
#[derive(Debug, Clone, PartialEq)]
pub enum ProbeOutcome {
    /// A usable meter; the text describes it.
    Accepted(String),
    /// Why there is no usable meter here.
    Rejected(String),
}

/// One place [`discover`] looked, and what it found there.
#[derive(Debug, Clone, PartialEq)]
pub struct Probe {
    /// The meter kind probed, e.g. `rapl`.
    pub kind: &'static str,
    /// The path (or library) looked at.
    pub location: String,
    pub outcome: ProbeOutcome,
}

impl Probe {
    fn rejected(
        kind: &'static str,
        location: impl fmt::Display,
        reason: impl Into<String>,
    ) -> Self {
        Probe {
            kind,
            location: location.to_string(),
            outcome: ProbeOutcome::Rejected(reason.into()),
        }
    }

    fn accepted(kind: &'static str, location: impl fmt::Display, what: impl Into<String>) -> Self {
        Probe {
            kind,
            location: location.to_string(),
            outcome: ProbeOutcome::Accepted(what.into()),
        }
    }
}

impl fmt::Display for Probe {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.outcome {
            ProbeOutcome::Accepted(what) => {
                write!(f, "{:<22} {}: found {what}", self.kind, self.location)
            }
            ProbeOutcome::Rejected(why) => {
                write!(f, "{:<22} {}: rejected: {why}", self.kind, self.location)
            }
        }
    }
}

/// Where discovery looks.
#[derive(Debug, Clone)]
pub struct DiscoverOptions {
    /// Root of the filesystem holding `sys/` (`/` on a real board).
    pub root: PathBuf,
    /// The NVML library to load; `None` skips NVML.
    pub nvml_library: Option<PathBuf>,
}

impl Default for DiscoverOptions {
    fn default() -> Self {
        DiscoverOptions {
            root: PathBuf::from("/"),
            nvml_library: Some(PathBuf::from(nvml::DEFAULT_LIBRARY)),
        }
    }
}

/// Every meter found, best first (a board's input rail before a CPU package or a GPU alone),
/// and every place looked at.
pub struct Discovery {
    pub meters: Vec<Box<dyn PowerMeter>>,
    pub probes: Vec<Probe>,
}

/// Probes every meter kind.
pub fn discover(options: &DiscoverOptions) -> Discovery {
    let mut meters: Vec<Box<dyn PowerMeter>> = Vec::new();
    let mut probes = Vec::new();
    let root = options.root.as_path();
    let (found, mut looked) = ina3221::discover_iio(root);
    meters.extend(found.map(|m| Box::new(m) as Box<dyn PowerMeter>));
    probes.append(&mut looked);
    let (found, mut looked) = ina3221::discover_hwmon(root);
    meters.extend(found.map(|m| Box::new(m) as Box<dyn PowerMeter>));
    probes.append(&mut looked);
    let (found, mut looked) = rapl::discover(root, Box::new(monotonic_clock()));
    meters.extend(found.map(|m| Box::new(m) as Box<dyn PowerMeter>));
    probes.append(&mut looked);
    let (found, mut looked) = hwmon::discover(root, &|| Box::new(monotonic_clock()) as Clock);
    meters.extend(
        found
            .into_iter()
            .map(|m| Box::new(m) as Box<dyn PowerMeter>),
    );
    probes.append(&mut looked);
    match &options.nvml_library {
        Some(library) => match nvml::NvmlMeter::open(library) {
            Ok(meter) => {
                probes.push(Probe::accepted("nvml", library.display(), meter.describe()));
                meters.push(Box::new(meter));
            }
            Err(error) => probes.push(Probe::rejected(
                "nvml",
                library.display(),
                error.to_string(),
            )),
        },
        None => probes.push(Probe::rejected("nvml", "-", "not probed (switched off)")),
    }
    probes.push(Probe::rejected(
        "csv",
        "-",
        "an external meter's log is never guessed: name it with --meter csv:PATH",
    ));
    Discovery { meters, probes }
}

/// Whether `--meter <selector>` picks a meter named `name`: the whole name, or its leading
/// `-`-separated parts (`jetson-ina3221` picks `jetson-ina3221-iio` and `…-hwmon`).
pub fn selects(selector: &str, name: &str) -> bool {
    name == selector
        || name
            .strip_prefix(selector)
            .is_some_and(|rest| rest.starts_with('-'))
}

/// A source of seconds on some fixed scale: monotonic for counters, Unix time for logs. Tests
/// drive it by hand.
pub type Clock = Box<dyn FnMut() -> f64>;

/// Seconds since the first call of this process's monotonic clock.
pub fn monotonic_clock() -> impl FnMut() -> f64 + 'static {
    let start = Instant::now();
    move || start.elapsed().as_secs_f64()
}

/// Rails of a board named for its CPU alone, or its GPU alone, by the conventions of Jetson
/// rail names (`POM_5V_CPU`, `VDD_SYS_GPU`); a shared rail (`VDD_CPU_GPU_CV`) is neither.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RailRole {
    /// The board's input: everything it draws.
    Input,
    Cpu,
    Gpu,
    Other,
}

pub fn rail_role(name: &str) -> RailRole {
    let upper = name.to_ascii_uppercase();
    let (cpu, gpu) = (upper.contains("CPU"), upper.contains("GPU"));
    if upper.ends_with("_IN") || upper == "VIN" {
        RailRole::Input
    } else if cpu && !gpu {
        RailRole::Cpu
    } else if gpu && !cpu {
        RailRole::Gpu
    } else {
        RailRole::Other
    }
}

/// Sums of the rails by role: the total is the input rail where there is one, else the sum
/// of every rail (then `total_is_sum`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RoleSums {
    pub total_w: f64,
    pub cpu_w: Option<f64>,
    pub gpu_w: Option<f64>,
}

pub(crate) fn role_sums(roles: &[RailRole], rails_w: &[f64]) -> RoleSums {
    let sum_of = |role: RailRole| {
        let mut any = false;
        let mut sum = 0.0;
        for (r, w) in roles.iter().zip(rails_w) {
            if *r == role {
                any = true;
                sum += w;
            }
        }
        any.then_some(sum)
    };
    RoleSums {
        total_w: sum_of(RailRole::Input).unwrap_or_else(|| rails_w.iter().sum()),
        cpu_w: sum_of(RailRole::Cpu),
        gpu_w: sum_of(RailRole::Gpu),
    }
}

/// `root` joined with an absolute sysfs path written without its leading `/`.
pub(crate) fn under(root: &Path, path: &str) -> PathBuf {
    root.join(path.trim_start_matches('/'))
}

#[cfg(test)]
mod tests;
