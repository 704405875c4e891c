//! The Jetson boards' INA3221 power monitors, in both driver generations:
//!
//! - L4T 32 and older (Nano, TX1, TX2, Xavier): the `ina3221x` IIO driver,
//!   `/sys/bus/i2c/drivers/ina3221x/<bus>-<addr>/iio:deviceN/in_powerK_input` in mW with the
//!   rail's name in `rail_name_K`;
//! - JetPack 5 and later (Orin, and Xavier on newer L4T): the mainline hwmon driver,
//!   `/sys/class/hwmon/hwmonN/` with `name` = `ina3221`, `in{K}_input` in mV,
//!   `curr{K}_input` in mA and the rail's name in `in{K}_label`.
//!
//! Rails are found by their names, never by fixed paths: the board's input rail (`POM_5V_IN`,
//! `VDD_IN`) is the total, `…CPU` and `…GPU` rails are the CPU and GPU. A board without an
//! input rail (AGX Xavier and Orin) is read as the sum of its rails, and says so.

use super::sysfs::{channel_number, entries, read_text, read_u64};
use super::{rail_role, role_sums, under, MeterError, PowerMeter, PowerReading, Probe, RailRole};
use std::path::{Path, PathBuf};

pub const IIO_NAME: &str = "jetson-ina3221-iio";
pub const HWMON_NAME: &str = "jetson-ina3221-hwmon";
const IIO_DRIVER_DIR: &str = "sys/bus/i2c/drivers/ina3221x";
pub(crate) const HWMON_CLASS_DIR: &str = "sys/class/hwmon";

/// Where a rail's power comes from.
#[derive(Debug, Clone)]
enum RailSource {
    /// The IIO driver's power in mW.
    PowerMw(PathBuf),
    /// The hwmon driver's bus voltage in mV and current in mA.
    VoltageCurrent { voltage: PathBuf, current: PathBuf },
}

impl RailSource {
    fn read_w(&self) -> Result<f64, MeterError> {
        match self {
            RailSource::PowerMw(path) => Ok(read_u64(path)? as f64 * 1e-3),
            RailSource::VoltageCurrent { voltage, current } => {
                let mv = read_u64(voltage)? as f64;
                let ma = read_u64(current)? as f64;
                Ok(mv * ma * 1e-6)
            }
        }
    }
}

#[derive(Debug, Clone)]
struct Rail {
    name: String,
    role: RailRole,
    source: RailSource,
}

/// An INA3221 meter: the usable rails of every INA3221 of one driver generation.
#[derive(Debug)]
pub struct Ina3221Meter {
    name: &'static str,
    location: PathBuf,
    rails: Vec<Rail>,
    roles: Vec<RailRole>,
}

impl Ina3221Meter {
    fn new(name: &'static str, location: PathBuf, rails: Vec<Rail>) -> Self {
        let roles = rails.iter().map(|rail| rail.role).collect();
        Ina3221Meter {
            name,
            location,
            rails,
            roles,
        }
    }

    fn total_rails(&self) -> String {
        let inputs: Vec<&str> = self
            .rails
            .iter()
            .filter(|rail| rail.role == RailRole::Input)
            .map(|rail| rail.name.as_str())
            .collect();
        if inputs.is_empty() {
            let all: Vec<&str> = self.rails.iter().map(|rail| rail.name.as_str()).collect();
            format!("sum of rails {} (no board input rail)", all.join("+"))
        } else {
            format!("input rail {}", inputs.join("+"))
        }
    }
}

impl PowerMeter for Ina3221Meter {
    fn name(&self) -> &str {
        self.name
    }

    fn describe(&self) -> String {
        format!(
            "INA3221 ({}) at {}: total = {}; rails {}",
            if self.name == IIO_NAME {
                "ina3221x IIO driver"
            } else {
                "hwmon driver"
            },
            self.location.display(),
            self.total_rails(),
            self.rails().join(", ")
        )
    }

    fn rails(&self) -> Vec<String> {
        self.rails.iter().map(|rail| rail.name.clone()).collect()
    }

    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let rails_w = self
            .rails
            .iter()
            .map(|rail| rail.source.read_w())
            .collect::<Result<Vec<f64>, _>>()?;
        let sums = role_sums(&self.roles, &rails_w);
        Ok(PowerReading {
            total_w: sums.total_w,
            cpu_w: sums.cpu_w,
            gpu_w: sums.gpu_w,
            rails_w,
        })
    }
}

/// What probing one device's channels gave: the usable rails and a note for each unusable one.
#[derive(Default)]
struct DeviceRails {
    rails: Vec<Rail>,
    notes: Vec<String>,
    /// Input rails that are named but unreadable: the meter cannot give the board's total.
    broken_inputs: Vec<String>,
}

impl DeviceRails {
    /// Keeps the rail if a first reading works.
    fn try_rail(&mut self, name: String, source: RailSource) {
        let role = rail_role(&name);
        match source.read_w() {
            Ok(_) => self.rails.push(Rail { name, role, source }),
            Err(error) => {
                if role == RailRole::Input {
                    self.broken_inputs.push(name.clone());
                }
                self.notes.push(format!("rail {name} skipped: {error}"));
            }
        }
    }

    fn summary(&self) -> String {
        let names: Vec<&str> = self.rails.iter().map(|r| r.name.as_str()).collect();
        let mut text = if names.is_empty() {
            "no readable rail".to_string()
        } else {
            format!("rails {}", names.join(", "))
        };
        for note in &self.notes {
            text += &format!("; {note}");
        }
        text
    }
}

/// Builds the meter from every device's rails, or says why there is none.
fn assemble(
    kind: &'static str,
    location: PathBuf,
    devices: Vec<(PathBuf, DeviceRails)>,
    probes: &mut Vec<Probe>,
) -> Option<Ina3221Meter> {
    let mut rails = Vec::new();
    let mut broken_inputs = Vec::new();
    for (path, device) in devices {
        if device.rails.is_empty() {
            probes.push(Probe::rejected(kind, path.display(), device.summary()));
        } else {
            probes.push(Probe::accepted(kind, path.display(), device.summary()));
        }
        rails.extend(device.rails);
        broken_inputs.extend(device.broken_inputs);
    }
    if !broken_inputs.is_empty() {
        probes.push(Probe::rejected(
            kind,
            location.display(),
            format!(
                "the board's input rail {} cannot be read, and the other rails do not add up to the board's power",
                broken_inputs.join(", ")
            ),
        ));
        return None;
    }
    if rails.is_empty() {
        return None;
    }
    Some(Ina3221Meter::new(kind, location, rails))
}

/// The `ina3221x` IIO driver's devices (L4T 32 and older).
pub fn discover_iio(root: &Path) -> (Option<Ina3221Meter>, Vec<Probe>) {
    let driver = under(root, IIO_DRIVER_DIR);
    let mut probes = Vec::new();
    // `<bus>-<addr>` entries are the devices; the driver folder also holds bind, unbind, uevent.
    let is_device = |name: &str| {
        name.split_once('-').is_some_and(|(bus, addr)| {
            !bus.is_empty()
                && bus.bytes().all(|b| b.is_ascii_digit())
                && addr.len() == 4
                && addr.bytes().all(|b| b.is_ascii_hexdigit())
        })
    };
    let devices = match entries(&driver, is_device) {
        Ok(devices) => devices,
        Err(error) => {
            probes.push(Probe::rejected(
                IIO_NAME,
                driver.display(),
                format!("cannot list: {error}"),
            ));
            return (None, probes);
        }
    };
    if devices.is_empty() {
        let why = if driver.is_dir() {
            "the ina3221x driver is bound to no device"
        } else {
            "absent: no ina3221x IIO driver (it is the INA3221 driver of Jetson L4T 32 and older)"
        };
        probes.push(Probe::rejected(IIO_NAME, driver.display(), why));
        return (None, probes);
    }
    let mut found = Vec::new();
    for (_, device) in devices {
        let iio = match entries(&device, |n| n.starts_with("iio:device")) {
            Ok(iio) => iio,
            Err(error) => {
                probes.push(Probe::rejected(
                    IIO_NAME,
                    device.display(),
                    format!("cannot list: {error}"),
                ));
                continue;
            }
        };
        if iio.is_empty() {
            probes.push(Probe::rejected(
                IIO_NAME,
                device.display(),
                "no iio:device folder",
            ));
        }
        for (_, dir) in iio {
            found.push((dir.clone(), iio_rails(&dir)));
        }
    }
    let meter = assemble(IIO_NAME, driver, found, &mut probes);
    (meter, probes)
}

/// The rails of one IIO device: `rail_name_K` names channel K, `in_powerK_input` its mW.
fn iio_rails(dir: &Path) -> DeviceRails {
    let mut device = DeviceRails::default();
    let names = match entries(dir, |n| channel_number(n, "rail_name_", "").is_some()) {
        Ok(names) => names,
        Err(error) => {
            device.notes.push(format!("cannot list: {error}"));
            return device;
        }
    };
    if names.is_empty() {
        device.notes.push("no rail_name_K file".to_string());
    }
    for (file, path) in names {
        let channel = channel_number(&file, "rail_name_", "").unwrap_or_default();
        let name = match read_text(&path) {
            Ok(name) if !name.is_empty() => name,
            Ok(_) => {
                device.notes.push(format!("{file} is empty"));
                continue;
            }
            Err(error) => {
                device.notes.push(error.to_string());
                continue;
            }
        };
        let power = dir.join(format!("in_power{channel}_input"));
        device.try_rail(name, RailSource::PowerMw(power));
    }
    device
}

/// hwmon devices named `ina3221` (JetPack 5 and later).
pub fn discover_hwmon(root: &Path) -> (Option<Ina3221Meter>, Vec<Probe>) {
    let class = under(root, HWMON_CLASS_DIR);
    let mut probes = Vec::new();
    let hwmons = match entries(&class, |n| n.starts_with("hwmon")) {
        Ok(hwmons) => hwmons,
        Err(error) => {
            probes.push(Probe::rejected(
                HWMON_NAME,
                class.display(),
                format!("cannot list: {error}"),
            ));
            return (None, probes);
        }
    };
    let ours: Vec<PathBuf> = hwmons
        .into_iter()
        .filter(|(_, dir)| read_text(&dir.join("name")).is_ok_and(|n| n == "ina3221"))
        .map(|(_, dir)| dir)
        .collect();
    if ours.is_empty() {
        let why = if class.is_dir() {
            "no hwmon device named ina3221 (the INA3221 driver of JetPack 5 and later)"
        } else {
            "absent: no hwmon class"
        };
        probes.push(Probe::rejected(HWMON_NAME, class.display(), why));
        return (None, probes);
    }
    let found = ours
        .into_iter()
        .map(|dir| {
            let rails = hwmon_rails(&dir);
            (dir, rails)
        })
        .collect();
    let meter = assemble(HWMON_NAME, class, found, &mut probes);
    (meter, probes)
}

/// The rails of one hwmon ina3221: channels 1 to 3 that have a label other than `NC`.
fn hwmon_rails(dir: &Path) -> DeviceRails {
    let mut device = DeviceRails::default();
    for channel in 1..=3 {
        let label = dir.join(format!("in{channel}_label"));
        let name = match read_text(&label) {
            Ok(name) if name.is_empty() || name == "NC" => continue,
            Ok(name) => name,
            // The driver shows a label only for channels the device tree names.
            Err(MeterError::Io { source, .. }) if source.kind() == std::io::ErrorKind::NotFound => {
                continue
            }
            Err(error) => {
                device.notes.push(error.to_string());
                continue;
            }
        };
        if read_text(&dir.join(format!("in{channel}_enable"))).is_ok_and(|e| e == "0") {
            device.notes.push(format!("rail {name} skipped: disabled"));
            continue;
        }
        device.try_rail(
            name,
            RailSource::VoltageCurrent {
                voltage: dir.join(format!("in{channel}_input")),
                current: dir.join(format!("curr{channel}_input")),
            },
        );
    }
    if device.rails.is_empty() && device.notes.is_empty() {
        device.notes.push("no labelled channel".to_string());
    }
    device
}
