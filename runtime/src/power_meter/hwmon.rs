//! Any hwmon device with power or energy channels (`/sys/class/hwmon/hwmonN/`):
//! `power{K}_input` or `power{K}_average` in µW, `energy{K}_input` in µJ (a counter), with
//! the channel's name in `power{K}_label` / `energy{K}_label`. One meter per device, its total
//! the sum of its channels; the INA3221 has its own meter ([`super::ina3221`]).

use super::counter::EnergyCounter;
use super::ina3221::HWMON_CLASS_DIR;
use super::sysfs::{channel_number, entries, read_text, read_u64};
use super::{
    rail_role, role_sums, under, Clock, MeterError, PowerMeter, PowerReading, Probe, RailRole,
};
use std::path::{Path, PathBuf};

pub const KIND: &str = "hwmon";

enum Source {
    PowerUw(PathBuf),
    Energy {
        path: PathBuf,
        counter: EnergyCounter,
    },
}

struct Channel {
    name: String,
    source: Source,
}

/// One hwmon device's power and energy channels.
pub struct HwmonMeter {
    /// `hwmon-<device name>`.
    name: String,
    dir: PathBuf,
    channels: Vec<Channel>,
    roles: Vec<RailRole>,
    clock: Clock,
}

impl PowerMeter for HwmonMeter {
    fn name(&self) -> &str {
        &self.name
    }

    fn describe(&self) -> String {
        format!(
            "hwmon device at {}: total = sum of {}",
            self.dir.display(),
            self.rails().join(" + ")
        )
    }

    fn rails(&self) -> Vec<String> {
        self.channels.iter().map(|c| c.name.clone()).collect()
    }

    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let now_s = (self.clock)();
        let mut rails_w = Vec::with_capacity(self.channels.len());
        for channel in &mut self.channels {
            rails_w.push(match &mut channel.source {
                Source::PowerUw(path) => read_u64(path)? as f64 * 1e-6,
                Source::Energy { path, counter } => counter.update(read_u64(path)?, now_s)?,
            });
        }
        let sums = role_sums(&self.roles, &rails_w);
        Ok(PowerReading {
            // The device's own channels add up: an input-named one is not the board's total.
            total_w: rails_w.iter().sum(),
            cpu_w: sums.cpu_w,
            gpu_w: sums.gpu_w,
            rails_w,
        })
    }
}

/// The files to read: each `power{K}_input` (or `power{K}_average` where a channel has no
/// input); only where the device has no power channel, its `energy{K}_input` counters (a
/// device with both may count the same rail twice).
fn channel_files(dir: &Path) -> Result<Vec<(u32, String, PathBuf)>, std::io::Error> {
    let files = entries(dir, |n| n.starts_with("power") || n.starts_with("energy"))?;
    let mut chosen: Vec<(u32, String, PathBuf)> = Vec::new();
    for (prefix, suffix) in [
        ("power", "_input"),
        ("power", "_average"),
        ("energy", "_input"),
    ] {
        if prefix == "energy" && !chosen.is_empty() {
            break;
        }
        for (file, path) in &files {
            let Some(k) = channel_number(file, prefix, suffix) else {
                continue;
            };
            if !chosen.iter().any(|(c, _, _)| *c == k) {
                chosen.push((k, file.clone(), path.clone()));
            }
        }
    }
    chosen.sort_by_key(|(k, _, _)| *k);
    Ok(chosen)
}

/// Why an hwmon device gives no meter.
#[derive(Debug, thiserror::Error)]
enum OpenError {
    #[error("cannot list: {0}")]
    List(#[source] std::io::Error),
    #[error("{device}: no power*_input, power*_average or energy*_input channel")]
    NoChannel { device: String },
    #[error("{device}: no readable channel; {}", notes.join("; "))]
    NoReadableChannel { device: String, notes: Vec<String> },
}

fn open_device(
    dir: &Path,
    device: &str,
    new_clock: &dyn Fn() -> Clock,
) -> Result<(Vec<Channel>, Vec<String>, Clock), OpenError> {
    let files = channel_files(dir).map_err(OpenError::List)?;
    if files.is_empty() {
        return Err(OpenError::NoChannel {
            device: device.to_string(),
        });
    }
    let mut clock = new_clock();
    let now_s = clock();
    let mut channels = Vec::new();
    let mut notes = Vec::new();
    for (k, file, path) in files {
        let is_energy = file.starts_with("energy");
        let label_file = dir.join(format!(
            "{}{k}_label",
            if is_energy { "energy" } else { "power" }
        ));
        let name = read_text(&label_file)
            .ok()
            .filter(|l| !l.is_empty())
            .unwrap_or_else(|| file.trim_end_matches("_input").to_string());
        let opened = read_u64(&path).and_then(|now_uj| {
            Ok(if is_energy {
                Source::Energy {
                    counter: EnergyCounter::new(path.clone(), None, now_uj, now_s)?,
                    path: path.clone(),
                }
            } else {
                Source::PowerUw(path.clone())
            })
        });
        match opened {
            Ok(source) => channels.push(Channel { name, source }),
            Err(error) => notes.push(format!("channel {name} skipped: {error}")),
        }
    }
    if channels.is_empty() {
        return Err(OpenError::NoReadableChannel {
            device: device.to_string(),
            notes,
        });
    }
    Ok((channels, notes, clock))
}

pub fn discover(root: &Path, new_clock: &dyn Fn() -> Clock) -> (Vec<HwmonMeter>, Vec<Probe>) {
    let class = under(root, HWMON_CLASS_DIR);
    let mut probes = Vec::new();
    let mut meters: Vec<HwmonMeter> = Vec::new();
    let hwmons = match entries(&class, |n| n.starts_with("hwmon")) {
        Ok(hwmons) => hwmons,
        Err(error) => {
            probes.push(Probe::rejected(
                KIND,
                class.display(),
                format!("cannot list: {error}"),
            ));
            return (meters, probes);
        }
    };
    if hwmons.is_empty() {
        let why = if class.is_dir() {
            "no hwmon device"
        } else {
            "absent: no hwmon class"
        };
        probes.push(Probe::rejected(KIND, class.display(), why));
    }
    for (id, dir) in hwmons {
        let device = match read_text(&dir.join("name")) {
            Ok(device) => device,
            Err(error) => {
                probes.push(Probe::rejected(KIND, dir.display(), error.to_string()));
                continue;
            }
        };
        if device == "ina3221" {
            continue;
        }
        match open_device(&dir, &device, new_clock) {
            Ok((channels, notes, clock)) => {
                let slug: String = device
                    .chars()
                    .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
                    .collect();
                let mut name = format!("{KIND}-{slug}");
                if meters.iter().any(|m| m.name == name) {
                    name = format!("{name}-{id}");
                }
                let roles = channels.iter().map(|c| rail_role(&c.name)).collect();
                let meter = HwmonMeter {
                    name,
                    dir: dir.clone(),
                    channels,
                    roles,
                    clock,
                };
                let mut what = format!("{}: {}", meter.name, meter.describe());
                for note in notes {
                    what += &format!("; {note}");
                }
                probes.push(Probe::accepted(KIND, dir.display(), what));
                meters.push(meter);
            }
            Err(why) => probes.push(Probe::rejected(KIND, dir.display(), why.to_string())),
        }
    }
    (meters, probes)
}
