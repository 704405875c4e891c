//! Every meter on directory trees laid out like the real sysfs: values as the kernel prints
//! them (a number and a newline), driver folders with their other files, missing rails,
//! unreadable files, garbage and counters that wrap.

use super::counter::EnergyCounter;
use super::*;
use std::cell::Cell;
use std::path::Path;
use std::rc::Rc;

fn write(root: &Path, rel: &str, text: &str) {
    let path = root.join(rel);
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
}

/// A file the meter cannot read: a directory in its place (the tests run as root, who reads
/// any file whatever its mode).
fn unreadable(root: &Path, rel: &str) {
    let path = root.join(rel);
    let _ = std::fs::remove_file(&path);
    std::fs::create_dir_all(path).unwrap();
}

fn manual_clock() -> (Rc<Cell<f64>>, Clock) {
    let time = Rc::new(Cell::new(100.0));
    let read = time.clone();
    (time, Box::new(move || read.get()))
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

fn rejected_reason<'a>(probes: &'a [Probe], kind: &str) -> Vec<&'a str> {
    probes
        .iter()
        .filter(|p| p.kind == kind)
        .filter_map(|p| match &p.outcome {
            ProbeOutcome::Rejected(why) => Some(why.as_str()),
            ProbeOutcome::Accepted(_) => None,
        })
        .collect()
}

const NANO_IIO: &str = "sys/bus/i2c/drivers/ina3221x/6-0040/iio:device0";

/// A Jetson Nano on L4T 32: one INA3221, IIO driver.
fn nano_iio(root: &Path) {
    for file in ["bind", "unbind", "uevent"] {
        write(root, &format!("sys/bus/i2c/drivers/ina3221x/{file}"), "");
    }
    for (k, rail, mw, ma, mv) in [
        (0, "POM_5V_IN", "3197", "632", "5056"),
        (1, "POM_5V_GPU", "78", "16", "4992"),
        (2, "POM_5V_CPU", "1076", "216", "4976"),
    ] {
        write(
            root,
            &format!("{NANO_IIO}/rail_name_{k}"),
            &format!("{rail}\n"),
        );
        write(
            root,
            &format!("{NANO_IIO}/in_power{k}_input"),
            &format!("{mw}\n"),
        );
        write(
            root,
            &format!("{NANO_IIO}/in_current{k}_input"),
            &format!("{ma}\n"),
        );
        write(
            root,
            &format!("{NANO_IIO}/in_voltage{k}_input"),
            &format!("{mv}\n"),
        );
    }
    write(root, &format!("{NANO_IIO}/name"), "ina3221x\n");
}

#[test]
fn iio_ina3221_reads_rails_by_name() {
    let dir = tempfile::tempdir().unwrap();
    nano_iio(dir.path());
    let (meter, probes) = ina3221::discover_iio(dir.path());
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(meter.name(), "jetson-ina3221-iio");
    assert_eq!(meter.rails(), ["POM_5V_IN", "POM_5V_GPU", "POM_5V_CPU"]);
    assert!(meter.describe().contains("input rail POM_5V_IN"));
    let r = meter.read().unwrap();
    assert!(close(r.total_w, 3.197));
    assert_eq!(r.cpu_w, Some(1.076));
    assert_eq!(r.gpu_w, Some(0.078));
    assert_eq!(r.rails_w, [3.197, 0.078, 1.076]);
    // Read live: the next reading sees the driver's new value.
    write(dir.path(), &format!("{NANO_IIO}/in_power0_input"), "4210\n");
    assert!(close(meter.read().unwrap().total_w, 4.21));
    // A value gone bad mid-sweep is an error naming the file, not a number.
    write(dir.path(), &format!("{NANO_IIO}/in_power0_input"), "-12\n");
    let error = meter.read().unwrap_err().to_string();
    assert!(
        error.contains("in_power0_input") && error.contains("`-12`"),
        "{error}"
    );
}

#[test]
fn iio_ina3221_on_two_devices_finds_the_input_rail_on_either() {
    // A TX2: the input rail is on the second device.
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    for (device, rails) in [
        ("0-0040", ["VDD_SYS_GPU", "VDD_SYS_SOC", "VDD_4V0_WIFI"]),
        ("0-0041", ["VDD_IN", "VDD_SYS_CPU", "VDD_SYS_DDR"]),
    ] {
        for (k, rail) in rails.iter().enumerate() {
            let iio = if device == "0-0040" {
                "iio:device0"
            } else {
                "iio:device1"
            };
            let base = format!("sys/bus/i2c/drivers/ina3221x/{device}/{iio}");
            write(root, &format!("{base}/rail_name_{k}"), &format!("{rail}\n"));
            write(
                root,
                &format!("{base}/in_power{k}_input"),
                &format!("{}\n", 1000 + 100 * k),
            );
        }
    }
    let (meter, probes) = ina3221::discover_iio(root);
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    let r = meter.read().unwrap();
    // VDD_IN is channel 0 of the second device: 1000 mW.
    assert!(close(r.total_w, 1.0), "{r:?}");
    assert!(close(r.gpu_w.unwrap(), 1.0));
    assert!(close(r.cpu_w.unwrap(), 1.1));
    assert_eq!(r.rails_w.len(), 6);
}

#[test]
fn iio_ina3221_skips_a_missing_or_bad_rail_but_never_the_input() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    nano_iio(root);
    // GPU rail without its power file, CPU rail with garbage: the meter keeps the input.
    std::fs::remove_file(root.join(format!("{NANO_IIO}/in_power1_input"))).unwrap();
    write(root, &format!("{NANO_IIO}/in_power2_input"), "n/a\n");
    let (meter, probes) = ina3221::discover_iio(root);
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(meter.rails(), ["POM_5V_IN"]);
    let r = meter.read().unwrap();
    assert!(close(r.total_w, 3.197));
    assert_eq!((r.cpu_w, r.gpu_w), (None, None));
    let found = format!("{}", probes[0]);
    assert!(
        found.contains("rail POM_5V_GPU skipped") && found.contains("in_power1_input"),
        "{found}"
    );
    assert!(
        found.contains("rail POM_5V_CPU skipped") && found.contains("`n/a`"),
        "{found}"
    );

    // The input rail unreadable: no meter, rather than the other rails passed off as the total.
    unreadable(root, &format!("{NANO_IIO}/in_power0_input"));
    let (meter, probes) = ina3221::discover_iio(root);
    assert!(meter.is_none());
    let reasons = rejected_reason(&probes, "jetson-ina3221-iio").join("\n");
    assert!(
        reasons.contains("input rail POM_5V_IN cannot be read"),
        "{reasons}"
    );
}

#[test]
fn iio_ina3221_absent_or_empty_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (meter, probes) = ina3221::discover_iio(dir.path());
    assert!(meter.is_none());
    assert!(rejected_reason(&probes, "jetson-ina3221-iio")[0].starts_with("absent"));
    write(
        dir.path(),
        "sys/bus/i2c/drivers/ina3221x/uevent",
        "DRIVER=ina3221x\n",
    );
    let (_, probes) = ina3221::discover_iio(dir.path());
    assert!(rejected_reason(&probes, "jetson-ina3221-iio")[0].contains("bound to no device"));
    // A device whose rail names are empty.
    write(dir.path(), &format!("{NANO_IIO}/rail_name_0"), "\n");
    write(dir.path(), &format!("{NANO_IIO}/in_power0_input"), "100\n");
    let (meter, probes) = ina3221::discover_iio(dir.path());
    assert!(meter.is_none());
    assert!(format!("{probes:?}").contains("rail_name_0 is empty"));
}

/// An Orin Nano on JetPack 5+: the hwmon ina3221 beside a fan's hwmon without power.
fn orin_hwmon(root: &Path) {
    write(root, "sys/class/hwmon/hwmon0/name", "pwmfan\n");
    write(root, "sys/class/hwmon/hwmon0/pwm1", "0\n");
    let dev = "sys/class/hwmon/hwmon1";
    write(root, &format!("{dev}/name"), "ina3221\n");
    for (k, label, mv, ma) in [
        (1, "VDD_IN", "5072", "1208"),
        (2, "VDD_CPU_GPU_CV", "5064", "320"),
        (3, "VDD_SOC", "5064", "288"),
    ] {
        write(root, &format!("{dev}/in{k}_label"), &format!("{label}\n"));
        write(root, &format!("{dev}/in{k}_input"), &format!("{mv}\n"));
        write(root, &format!("{dev}/curr{k}_input"), &format!("{ma}\n"));
        write(root, &format!("{dev}/in{k}_enable"), "1\n");
        // Shunt voltages and limits the meter does not use.
        write(root, &format!("{dev}/in{}_input", k + 3), "12\n");
        write(root, &format!("{dev}/curr{k}_crit"), "10000\n");
    }
    write(root, &format!("{dev}/curr4_input"), "1816\n");
}

#[test]
fn hwmon_ina3221_reads_voltage_times_current() {
    let dir = tempfile::tempdir().unwrap();
    orin_hwmon(dir.path());
    let (meter, probes) = ina3221::discover_hwmon(dir.path());
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(meter.name(), "jetson-ina3221-hwmon");
    assert_eq!(meter.rails(), ["VDD_IN", "VDD_CPU_GPU_CV", "VDD_SOC"]);
    let r = meter.read().unwrap();
    assert!(close(r.total_w, 5.072 * 1.208), "{r:?}");
    assert!(close(r.rails_w[1], 5.064 * 0.320));
    // The shared CPU+GPU rail is neither the CPU's nor the GPU's.
    assert_eq!((r.cpu_w, r.gpu_w), (None, None));
    // The fan's hwmon is no ina3221 and is left to the generic probe, which rejects it.
    let (meters, probes) = hwmon::discover(dir.path(), &|| manual_clock().1);
    assert!(meters.is_empty());
    let reasons = rejected_reason(&probes, "hwmon");
    assert_eq!(reasons.len(), 1);
    assert!(reasons[0].contains("pwmfan: no power"), "{reasons:?}");
}

#[test]
fn hwmon_ina3221_without_input_rail_sums_and_skips_nc_and_disabled() {
    // An AGX Orin: two devices, no board input rail, unused channels labelled NC.
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    for (dev, rails) in [
        (
            "hwmon3",
            [
                ("VDD_GPU_SOC", "1000"),
                ("VDD_CPU_CV", "500"),
                ("VIN_SYS_5V0", "800"),
            ],
        ),
        (
            "hwmon4",
            [("NC", "0"), ("VDDQ_VDD2_1V8AO", "200"), ("NC", "0")],
        ),
    ] {
        write(root, &format!("sys/class/hwmon/{dev}/name"), "ina3221\n");
        for (i, (label, ma)) in rails.iter().enumerate() {
            let k = i + 1;
            write(
                root,
                &format!("sys/class/hwmon/{dev}/in{k}_label"),
                &format!("{label}\n"),
            );
            write(
                root,
                &format!("sys/class/hwmon/{dev}/in{k}_input"),
                "5000\n",
            );
            write(
                root,
                &format!("sys/class/hwmon/{dev}/curr{k}_input"),
                &format!("{ma}\n"),
            );
        }
    }
    write(root, "sys/class/hwmon/hwmon4/in2_enable", "0\n");
    let (meter, probes) = ina3221::discover_hwmon(root);
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(meter.rails(), ["VDD_GPU_SOC", "VDD_CPU_CV", "VIN_SYS_5V0"]);
    assert!(
        meter.describe().contains("sum of rails"),
        "{}",
        meter.describe()
    );
    assert!(format!("{probes:?}").contains("VDDQ_VDD2_1V8AO skipped: disabled"));
    let r = meter.read().unwrap();
    assert!(close(r.total_w, 5.0 * (1.0 + 0.5 + 0.8)), "{r:?}");
}

#[test]
fn hwmon_ina3221_missing_current_or_garbage() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    orin_hwmon(root);
    std::fs::remove_file(root.join("sys/class/hwmon/hwmon1/curr3_input")).unwrap();
    write(root, "sys/class/hwmon/hwmon1/in2_input", "5,064\n");
    let (meter, probes) = ina3221::discover_hwmon(root);
    let meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(meter.rails(), ["VDD_IN"]);
    let text = format!("{probes:?}");
    assert!(
        text.contains("curr3_input") && text.contains("`5,064`"),
        "{text}"
    );
    // Without the input rail's current: rejected.
    std::fs::remove_file(root.join("sys/class/hwmon/hwmon1/curr1_input")).unwrap();
    let (meter, probes) = ina3221::discover_hwmon(root);
    assert!(meter.is_none());
    assert!(rejected_reason(&probes, "jetson-ina3221-hwmon")
        .iter()
        .any(|r| r.contains("input rail VDD_IN")));
}

/// A laptop's RAPL: package with core and uncore, DRAM, the MMIO copy of the package.
fn rapl_tree(root: &Path, with_psys: bool) {
    let max = "262143328850\n";
    for (zone, name, energy) in [
        ("intel-rapl:0", "package-0", "1000000"),
        ("intel-rapl:0:0", "core", "400000"),
        ("intel-rapl:0:1", "uncore", "100000"),
        ("intel-rapl:0:2", "dram", "50000"),
        ("intel-rapl-mmio:0", "package-0", "1000000"),
    ] {
        write(
            root,
            &format!("sys/class/powercap/{zone}/name"),
            &format!("{name}\n"),
        );
        write(
            root,
            &format!("sys/class/powercap/{zone}/energy_uj"),
            &format!("{energy}\n"),
        );
        write(
            root,
            &format!("sys/class/powercap/{zone}/max_energy_range_uj"),
            max,
        );
        write(root, &format!("sys/class/powercap/{zone}/enabled"), "1\n");
    }
    if with_psys {
        write(root, "sys/class/powercap/intel-rapl:1/name", "psys\n");
        write(
            root,
            "sys/class/powercap/intel-rapl:1/energy_uj",
            "7000000\n",
        );
        write(
            root,
            "sys/class/powercap/intel-rapl:1/max_energy_range_uj",
            max,
        );
    }
}

fn set_energy(root: &Path, zone: &str, uj: u64) {
    write(
        root,
        &format!("sys/class/powercap/{zone}/energy_uj"),
        &format!("{uj}\n"),
    );
}

#[test]
fn rapl_turns_counters_into_watts_across_the_wrap() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    rapl_tree(root, false);
    let (time, clock) = manual_clock();
    let (meter, probes) = rapl::discover(root, clock);
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    assert_eq!(
        meter.rails(),
        [
            "package-0 (intel-rapl:0)",
            "core (intel-rapl:0:0)",
            "uncore (intel-rapl:0:1)",
            "dram (intel-rapl:0:2)"
        ]
    );
    // 0.5 s: package +5 J, core +2 J, uncore +0.5 J, DRAM +0.25 J.
    time.set(100.5);
    set_energy(root, "intel-rapl:0", 6_000_000);
    set_energy(root, "intel-rapl:0:0", 2_400_000);
    set_energy(root, "intel-rapl:0:1", 600_000);
    set_energy(root, "intel-rapl:0:2", 300_000);
    let r = meter.read().unwrap();
    assert!(close(r.rails_w[0], 10.0), "{r:?}");
    assert!(close(r.total_w, 10.0 + 0.5), "package + DRAM: {r:?}");
    assert!(close(r.cpu_w.unwrap(), 4.0));
    assert!(close(r.gpu_w.unwrap(), 1.0));
    // The package counter wraps: 1 J below the top of its range, then 2 J above 0.
    let max = 262_143_328_850u64;
    set_energy(root, "intel-rapl:0", max - 1_000_000);
    time.set(101.0);
    meter.read().unwrap();
    set_energy(root, "intel-rapl:0", 2_000_000);
    time.set(101.5);
    let r = meter.read().unwrap();
    assert!(close(r.rails_w[0], 3.0 / 0.5), "{r:?}");
    // A counter above its range is garbage, said so.
    set_energy(root, "intel-rapl:0", max + 5);
    time.set(102.0);
    let error = meter.read().unwrap_err().to_string();
    assert!(error.contains("above its range"), "{error}");
    // No time between two readings: no power, an error.
    set_energy(root, "intel-rapl:0", 3_000_000);
    meter.read().unwrap();
    let error = meter.read().unwrap_err().to_string();
    assert!(error.contains("no time passed"), "{error}");
}

#[test]
fn rapl_platform_zone_is_the_total_and_bad_zones_are_rejected() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    rapl_tree(root, true);
    unreadable(root, "sys/class/powercap/intel-rapl:0:2/energy_uj");
    write(
        root,
        "sys/class/powercap/intel-rapl:0:1/max_energy_range_uj",
        "lots\n",
    );
    let (time, clock) = manual_clock();
    let (meter, probes) = rapl::discover(root, clock);
    let mut meter = meter.unwrap_or_else(|| panic!("{probes:#?}"));
    let reasons = rejected_reason(&probes, "rapl").join("\n");
    assert!(reasons.contains("intel-rapl:0:2/energy_uj"), "{reasons}");
    assert!(reasons.contains("`lots`"), "{reasons}");
    assert_eq!(meter.rails().len(), 3, "{:?}", meter.rails());
    time.set(102.0);
    set_energy(root, "intel-rapl:1", 7_000_000 + 30_000_000);
    set_energy(root, "intel-rapl:0", 1_000_000 + 20_000_000);
    let r = meter.read().unwrap();
    // psys alone, not psys + package: 30 J in 2 s.
    assert!(close(r.total_w, 15.0), "{r:?}");
    assert_eq!(r.gpu_w, None);
}

#[test]
fn rapl_absent_or_without_a_package_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let (meter, probes) = rapl::discover(dir.path(), manual_clock().1);
    assert!(meter.is_none());
    assert!(rejected_reason(&probes, "rapl")[0].starts_with("absent"));
    write(
        dir.path(),
        "sys/class/powercap/intel-rapl:0:0/name",
        "core\n",
    );
    write(
        dir.path(),
        "sys/class/powercap/intel-rapl:0:0/energy_uj",
        "5\n",
    );
    write(
        dir.path(),
        "sys/class/powercap/intel-rapl:0:0/max_energy_range_uj",
        "100\n",
    );
    let (meter, probes) = rapl::discover(dir.path(), manual_clock().1);
    assert!(meter.is_none());
    assert!(rejected_reason(&probes, "rapl")[0].contains("no package or psys zone"));
}

#[test]
fn energy_counter_arithmetic() {
    let path = PathBuf::from("energy_uj");
    let mut c = EnergyCounter::new(path.clone(), Some(1000), 900, 0.0).unwrap();
    assert_eq!(c.delta_uj(950).unwrap(), 50);
    // 900 → top (1000) is 100, then 0 → 30 is 30.
    assert_eq!(c.delta_uj(30).unwrap(), 130);
    assert!(close(c.update(30, 0.25).unwrap(), 130e-6 / 0.25));
    assert!(EnergyCounter::new(path.clone(), Some(1000), 1001, 0.0).is_err());
    // Without a range, going back is a reset: an error, then readings resume from there.
    let mut c = EnergyCounter::new(path, None, 5_000_000, 0.0).unwrap();
    let error = c.update(1_000_000, 1.0).unwrap_err();
    assert!(
        matches!(error, MeterError::CounterBackwards { .. }),
        "{error}"
    );
    assert!(close(c.update(3_000_000, 2.0).unwrap(), 2.0));
}

#[test]
fn hwmon_power_and_energy_channels() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path();
    // A GPU's average power with its label.
    write(root, "sys/class/hwmon/hwmon2/name", "amdgpu\n");
    write(root, "sys/class/hwmon/hwmon2/power1_average", "35000000\n");
    write(root, "sys/class/hwmon/hwmon2/power1_cap", "150000000\n");
    write(root, "sys/class/hwmon/hwmon2/power1_label", "PPT\n");
    // A device with energy counters only, one of them garbage.
    write(root, "sys/class/hwmon/hwmon5/name", "cpu_energy\n");
    write(root, "sys/class/hwmon/hwmon5/energy1_input", "1000000\n");
    write(root, "sys/class/hwmon/hwmon5/energy1_label", "Ecore000\n");
    write(root, "sys/class/hwmon/hwmon5/energy2_input", "2000000\n");
    write(root, "sys/class/hwmon/hwmon5/energy3_input", "0x12\n");
    // Unreadable name.
    unreadable(root, "sys/class/hwmon/hwmon7/name");
    let (time, _) = manual_clock();
    let clock_time = time.clone();
    let new_clock = move || -> Clock {
        let t = clock_time.clone();
        Box::new(move || t.get())
    };
    let (mut meters, probes) = hwmon::discover(root, &new_clock);
    let names: Vec<&str> = meters.iter().map(|m| m.name()).collect();
    assert_eq!(names, ["hwmon-amdgpu", "hwmon-cpu-energy"], "{probes:#?}");
    assert!(close(meters[0].read().unwrap().total_w, 35.0));
    assert_eq!(meters[0].rails(), ["PPT"]);
    assert_eq!(meters[1].rails(), ["Ecore000", "energy2"]);
    let text = format!("{probes:?}");
    assert!(
        text.contains("channel energy3 skipped") && text.contains("`0x12`"),
        "{text}"
    );
    assert!(text.contains("hwmon7/name"), "{text}");
    time.set(101.0);
    write(root, "sys/class/hwmon/hwmon5/energy1_input", "4000000\n");
    write(root, "sys/class/hwmon/hwmon5/energy2_input", "2500000\n");
    let r = meters[1].read().unwrap();
    assert!(close(r.total_w, 3.5), "{r:?}");
}

#[test]
fn csv_log_merges_readings_by_time() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("meter.csv");
    std::fs::write(&path, "timestamp_s,power_w\n99.8,5.0\n100.0,7.0\n").unwrap();
    let (time, clock) = manual_clock();
    let mut meter = csv_log::CsvLogMeter::open(&path, clock, 2.0).unwrap();
    // First read: the readings of the last max-age window.
    assert!(close(meter.read().unwrap().total_w, 6.0));
    // The logger appends two rows (the second still being written) and the sweep reads.
    let mut f = std::fs::OpenOptions::new()
        .append(true)
        .open(&path)
        .unwrap();
    use std::io::Write;
    write!(f, "100.1,9.0\n100.2,11.0\n100.3,1").unwrap();
    time.set(100.25);
    assert!(close(meter.read().unwrap().total_w, 10.0));
    // Nothing new (the half line is not a reading yet): the newest reading is held.
    time.set(100.28);
    assert!(close(meter.read().unwrap().total_w, 11.0));
    writeln!(f, "3.0").unwrap();
    time.set(100.4);
    assert!(close(meter.read().unwrap().total_w, 13.0));
    // The logger stopped: stale.
    time.set(103.0);
    let error = meter.read().unwrap_err().to_string();
    assert!(error.contains("2.7 s old"), "{error}");
    // Garbage names its line.
    writeln!(f, "103.1,lots").unwrap();
    let error = meter.read().unwrap_err();
    assert!(
        matches!(
            &error,
            MeterError::Csv {
                line: 7,
                source: csv_log::LineError::NotANumber { .. },
                ..
            }
        ),
        "{error:?}"
    );
    let message = error.to_string();
    assert!(
        message.contains("meter.csv:7: power_w `lots` is not a finite number"),
        "{message}"
    );
}

#[test]
fn csv_log_line_rules() {
    assert_eq!(csv_log::parse_line(" 1.5 , 2 "), Ok(Some((1.5, 2.0))));
    assert_eq!(csv_log::parse_line("   "), Ok(None));
    assert!(csv_log::parse_line("1,2,3")
        .unwrap_err()
        .to_string()
        .contains("3 cells"));
    assert!(csv_log::parse_line("1,-2")
        .unwrap_err()
        .to_string()
        .contains("negative"));
    assert!(csv_log::parse_line("nan,2")
        .unwrap_err()
        .to_string()
        .contains("timestamp_s"));
    // A cell that is no number keeps the parser's reason.
    let error = csv_log::parse_line("1,2 W").unwrap_err();
    let cause = std::error::Error::source(&error).expect("the float parser's error");
    assert!(error
        .to_string()
        .starts_with("power_w `2 W` is not a finite number"));
    assert!(error.to_string().contains(&cause.to_string()), "{error}");
    let readings = [(1.0, 2.0), (2.0, 4.0), (3.0, 9.0)];
    assert_eq!(csv_log::mean_in_window(&readings, 1.0, 3.0), Some(6.5));
    assert_eq!(csv_log::mean_in_window(&readings, 3.0, 4.0), None);
    let missing =
        csv_log::CsvLogMeter::open(Path::new("/nonexistent/log.csv"), manual_clock().1, 2.0);
    assert!(missing.is_err());
}

#[test]
fn nvml_absent_or_not_nvml_is_a_reason() {
    let error = nvml::NvmlMeter::open(Path::new("/nonexistent/libnvidia-ml.so.1"))
        .err()
        .unwrap();
    assert!(matches!(error, MeterError::NvmlLoad { .. }), "{error:?}");
    // The loader's error is kept, and its text (which file, why) is in the message.
    assert!(std::error::Error::source(&error).is_some());
    let message = error.to_string();
    assert!(message.contains("cannot load the library"), "{message}");
    assert!(
        message.contains("/nonexistent/libnvidia-ml.so.1"),
        "{message}"
    );
    // A real library that is not NVML.
    if let Ok(libc) = std::fs::canonicalize("/lib/x86_64-linux-gnu/libc.so.6") {
        let error = nvml::NvmlMeter::open(&libc).err().unwrap();
        assert!(std::error::Error::source(&error).is_some());
        assert!(error.to_string().contains("lacks nvmlInit_v2"), "{error}");
    }
}

/// On a machine with an NVIDIA GPU and driver this reads it; elsewhere it says it skipped.
#[test]
fn nvml_reads_a_real_gpu_where_there_is_one() {
    match nvml::NvmlMeter::open(Path::new(nvml::DEFAULT_LIBRARY)) {
        Err(why) => eprintln!("SKIP: no NVML here: {why}"),
        Ok(mut meter) => {
            let r = meter.read().unwrap();
            eprintln!("{}: {r:?}", meter.describe());
            assert_eq!(r.rails_w.len(), meter.rails().len());
            // Any GPU draws more than 1 W and less than 2 kW.
            for w in &r.rails_w {
                assert!((1.0..2000.0).contains(w), "{w} W");
            }
            assert!(close(r.total_w, r.rails_w.iter().sum()));
        }
    }
}

#[test]
fn discovery_on_an_empty_machine_lists_every_probe() {
    let dir = tempfile::tempdir().unwrap();
    let discovery = discover(&DiscoverOptions {
        root: dir.path().to_path_buf(),
        nvml_library: Some(PathBuf::from("/nonexistent/libnvidia-ml.so.1")),
    });
    assert!(discovery.meters.is_empty());
    let kinds: Vec<&str> = discovery.probes.iter().map(|p| p.kind).collect();
    assert_eq!(
        kinds,
        [
            "jetson-ina3221-iio",
            "jetson-ina3221-hwmon",
            "rapl",
            "hwmon",
            "nvml",
            "csv"
        ]
    );
    assert!(discovery
        .probes
        .iter()
        .all(|p| matches!(p.outcome, ProbeOutcome::Rejected(_))));
}

#[test]
fn discovery_orders_board_meters_first() {
    let dir = tempfile::tempdir().unwrap();
    nano_iio(dir.path());
    rapl_tree(dir.path(), false);
    orin_hwmon(dir.path());
    let discovery = discover(&DiscoverOptions {
        root: dir.path().to_path_buf(),
        nvml_library: None,
    });
    let names: Vec<&str> = discovery.meters.iter().map(|m| m.name()).collect();
    assert_eq!(
        names,
        ["jetson-ina3221-iio", "jetson-ina3221-hwmon", "rapl"]
    );
}

#[test]
fn selection_by_name() {
    assert!(selects("jetson-ina3221", "jetson-ina3221-iio"));
    assert!(selects("jetson-ina3221-hwmon", "jetson-ina3221-hwmon"));
    assert!(selects("hwmon", "hwmon-amdgpu"));
    assert!(!selects("hwmon", "jetson-ina3221-hwmon"));
    assert!(!selects("jetson-ina", "jetson-ina3221-iio"));
    assert!(!selects("rapl", "nvml"));
}

#[test]
fn rail_roles_follow_jetson_names() {
    use RailRole::*;
    for (name, role) in [
        ("POM_5V_IN", Input),
        ("VDD_IN", Input),
        ("POM_5V_CPU", Cpu),
        ("VDD_SYS_GPU", Gpu),
        ("VDD_CPU_GPU_CV", Other),
        ("VDD_SOC", Other),
        ("VIN_SYS_5V0", Other),
    ] {
        assert_eq!(rail_role(name), role, "{name}");
    }
}
