//! Linux powercap RAPL (x86 CPUs): `/sys/class/powercap/intel-rapl:N[:M]/energy_uj`, an
//! energy counter that wraps at `max_energy_range_uj`, with the zone's name in `name`.
//!
//! The total is the platform zone (`psys`) where there is one, else the packages plus DRAM;
//! the CPU is the `core` zones, the GPU the `uncore` zones (a client chip's integrated GPU).

use super::counter::EnergyCounter;
use super::sysfs::{entries, read_text, read_u64};
use super::{under, Clock, MeterError, PowerMeter, PowerReading, Probe};
use std::path::{Path, PathBuf};

pub const NAME: &str = "rapl";
const POWERCAP_DIR: &str = "sys/class/powercap";

#[derive(Debug)]
struct Zone {
    /// `package-0 (intel-rapl:0)`.
    label: String,
    name: String,
    energy: PathBuf,
    counter: EnergyCounter,
}

/// Every readable RAPL zone.
pub struct RaplMeter {
    location: PathBuf,
    zones: Vec<Zone>,
    in_total: Vec<bool>,
    clock: Clock,
}

impl RaplMeter {
    fn new(location: PathBuf, zones: Vec<Zone>, clock: Clock) -> Self {
        let has_platform = zones.iter().any(|zone| zone.name == "psys");
        let in_total = zones
            .iter()
            .map(|zone| {
                if has_platform {
                    zone.name == "psys"
                } else {
                    zone.name.starts_with("package") || zone.name == "dram"
                }
            })
            .collect();
        RaplMeter {
            location,
            zones,
            in_total,
            clock,
        }
    }
}

impl PowerMeter for RaplMeter {
    fn name(&self) -> &str {
        NAME
    }

    fn describe(&self) -> String {
        let total: Vec<&str> = self
            .zones
            .iter()
            .zip(&self.in_total)
            .filter(|(_, &t)| t)
            .map(|(zone, _)| zone.label.as_str())
            .collect();
        format!(
            "RAPL energy counters at {}: total = {}; zones {}",
            self.location.display(),
            total.join(" + "),
            self.rails().join(", ")
        )
    }

    fn rails(&self) -> Vec<String> {
        self.zones.iter().map(|zone| zone.label.clone()).collect()
    }

    fn read(&mut self) -> Result<PowerReading, MeterError> {
        let now_s = (self.clock)();
        let mut rails_w = Vec::with_capacity(self.zones.len());
        for zone in &mut self.zones {
            let now_uj = read_u64(&zone.energy)?;
            rails_w.push(zone.counter.update(now_uj, now_s)?);
        }
        let sum = |keep: &dyn Fn(usize) -> bool| -> Option<f64> {
            let picked: Vec<f64> = (0..rails_w.len())
                .filter(|&i| keep(i))
                .map(|i| rails_w[i])
                .collect();
            (!picked.is_empty()).then(|| picked.iter().sum())
        };
        Ok(PowerReading {
            total_w: sum(&|i| self.in_total[i]).unwrap_or(0.0),
            cpu_w: sum(&|i| self.zones[i].name == "core"),
            gpu_w: sum(&|i| self.zones[i].name == "uncore"),
            rails_w,
        })
    }
}

/// Opens one zone: its name, range and a first counter reading.
fn open_zone(dir: &Path, id: &str, now_s: f64) -> Result<Zone, MeterError> {
    let name = read_text(&dir.join("name"))?;
    let max_path = dir.join("max_energy_range_uj");
    let max_uj = read_u64(&max_path)?;
    if max_uj == 0 {
        return Err(MeterError::ZeroRange { path: max_path });
    }
    let energy = dir.join("energy_uj");
    let now_uj = read_u64(&energy).map_err(|error| match error {
        MeterError::Io { path, source }
            if source.kind() == std::io::ErrorKind::PermissionDenied =>
        {
            MeterError::RootOnly { path, source }
        }
        error => error,
    })?;
    let counter = EnergyCounter::new(energy.clone(), Some(max_uj), now_uj, now_s)?;
    Ok(Zone {
        label: format!("{name} ({id})"),
        name,
        energy,
        counter,
    })
}

pub fn discover(root: &Path, mut clock: Clock) -> (Option<RaplMeter>, Vec<Probe>) {
    let class = under(root, POWERCAP_DIR);
    let mut probes = Vec::new();
    // `intel-rapl:N` and `intel-rapl:N:M`; not `intel-rapl-mmio:N`, which repeats a package.
    let zones = match entries(&class, |n| n.starts_with("intel-rapl:")) {
        Ok(zones) => zones,
        Err(error) => {
            probes.push(Probe::rejected(
                NAME,
                class.display(),
                format!("cannot list: {error}"),
            ));
            return (None, probes);
        }
    };
    if zones.is_empty() {
        let why = if class.is_dir() {
            "no intel-rapl zone (the intel_rapl driver is not loaded, or the CPU has no RAPL)"
        } else {
            "absent: no powercap class (not an x86 machine with RAPL)"
        };
        probes.push(Probe::rejected(NAME, class.display(), why));
        return (None, probes);
    }
    let now_s = clock();
    let mut opened = Vec::new();
    for (id, dir) in zones {
        match open_zone(&dir, &id, now_s) {
            Ok(zone) => opened.push(zone),
            Err(error) => probes.push(Probe::rejected(NAME, dir.display(), error.to_string())),
        }
    }
    if opened.is_empty() {
        return (None, probes);
    }
    let meter = RaplMeter::new(class.clone(), opened, clock);
    if !meter.in_total.iter().any(|&t| t) {
        probes.push(Probe::rejected(
            NAME,
            class.display(),
            format!(
                "no package or psys zone among the readable zones {}",
                meter.rails().join(", ")
            ),
        ));
        return (None, probes);
    }
    probes.push(Probe::accepted(NAME, class.display(), meter.describe()));
    (Some(meter), probes)
}
