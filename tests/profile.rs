//! End-to-end tests of `qosrt profile`: the no-meter error, a whole sweep on a fake Jetson
//! sysfs tree whose profile `qosrt plan` then uses, an external meter's log, and `--from-csv`
//! on the seed's raw traces.

mod common;
use common::{output_text as text, qosrt, repo_root};

use power_models::profile::Profile;
use std::path::{Path, PathBuf};

fn write(root: &Path, rel: &str, text: &str) {
    let path = root.join(rel);
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, text).unwrap();
}

fn read_profile(path: &Path) -> Profile {
    let text = std::fs::read_to_string(path).unwrap();
    Profile::from_toml_str(&text)
        .unwrap_or_else(|e| panic!("{}: {}\n{text}", path.display(), e.message))
}

/// An Orin-style mainline hwmon INA3221, values as the driver prints them, beside a fan.
fn fake_jetson(root: &Path) {
    write(root, "sys/class/hwmon/hwmon0/name", "pwmfan\n");
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
    }
    write(
        root,
        "proc/device-tree/model",
        "NVIDIA Jetson Orin Nano Developer Kit\0",
    );
}

/// The landing phase, detection at two rates, the other two tasks held: quick.
const QUICK: &[&str] = &[
    "--phase",
    "landing",
    "--duration-s",
    "0.3",
    "--warmup-s",
    "0.1",
    "--rate-hz",
    "20",
    "--levels",
    "detection.rate_fps=0.5,10",
    "--levels",
    "tracking.period_ms=100",
    "--levels",
    "landing.period_ms=100",
    "--nvml-library",
    "/nonexistent/libnvidia-ml.so.1",
];

fn profile_args<'a>(root: &'a str, out: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["profile", "qos.toml", "--sysfs-root", root, "--out", out];
    args.extend_from_slice(QUICK);
    args.extend_from_slice(extra);
    args
}

#[test]
fn without_a_meter_it_fails_listing_every_probe() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("empty-root");
    std::fs::create_dir(&root).unwrap();
    let out = dir.path().join("p.toml");
    let output = qosrt(&profile_args(
        root.to_str().unwrap(),
        out.to_str().unwrap(),
        &[],
    ));
    let all = text(&output);
    assert_eq!(output.status.code(), Some(3), "{all}");
    assert!(all.contains("no power meter found"), "{all}");
    for kind in [
        "jetson-ina3221-iio",
        "jetson-ina3221-hwmon",
        "rapl",
        "hwmon",
        "nvml",
        "csv",
    ] {
        assert!(
            all.lines()
                .any(|l| l.trim_start().starts_with(kind) && l.contains("rejected")),
            "{kind} missing:\n{all}"
        );
    }
    assert!(
        all.contains("sys/bus/i2c/drivers/ina3221x: rejected: absent"),
        "{all}"
    );
    assert!(all.contains("/nonexistent/libnvidia-ml.so.1"), "{all}");
    assert!(!out.exists(), "no profile without a meter");
}

#[test]
fn a_fake_jetson_gives_a_profile_that_plan_uses() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    fake_jetson(&root);
    let out = dir.path().join("profiles/landing.toml");
    let csv = dir.path().join("landing.csv");
    let output = qosrt(&profile_args(
        root.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--powprofiler", csv.to_str().unwrap()],
    ));
    let all = text(&output);
    assert_eq!(output.status.code(), Some(0), "{all}");
    assert!(all.contains("hold  tracking.period_ms = 100"), "{all}");

    let profile = read_profile(&out);
    // The board from the device tree, the meter naming its input rail.
    assert_eq!(profile.board, "NVIDIA Jetson Orin Nano Developer Kit");
    assert!(
        profile.meter.contains("input rail VDD_IN"),
        "{}",
        profile.meter
    );
    assert_eq!(profile.knobs, ["detection.rate_fps"]);
    assert_eq!(profile.sample_rate_hz, Some(20.0));
    // The tree does not change, so every point is VDD_IN's mV × mA, without spread.
    let vdd_in_w = 5.072 * 1.208;
    let points: Vec<f64> = profile.samples.iter().map(|s| s.knobs[0]).collect();
    assert_eq!(points, [0.5, 10.0]);
    for sample in &profile.samples {
        assert!((sample.power_w - vdd_in_w).abs() < 1e-9, "{sample:?}");
        assert_eq!(sample.power_std_w, Some(0.0));
        assert!((sample.duration_s.unwrap() - 0.3).abs() < 0.1, "{sample:?}");
    }
    assert!((profile.idle_power_w.unwrap() - vdd_in_w).abs() < 1e-9);
    let source = profile.source.unwrap();
    assert!(
        source.contains("held: tracking.period_ms = 100, landing.period_ms = 100"),
        "{source}"
    );

    // The powprofiler CSV reads back to the same points.
    let exchanged = Profile::from_powprofiler_csv_with_rate(
        &std::fs::read_to_string(&csv).unwrap(),
        &["detection.rate_fps"],
        20.0,
    )
    .unwrap();
    assert_eq!(exchanged.samples.len(), 2);
    assert!((exchanged.samples[1].power_w - vdd_in_w).abs() < 1e-9);

    // `plan` on the reference mission with this profile for its landing phase.
    let reference = std::fs::read_to_string(repo_root().join("qos.toml")).unwrap();
    let shipped = repo_root().join("profiles/jetson-nano-seed");
    let config = reference
        .replace(
            "\"profiles/jetson-nano-seed/landing.toml\"",
            &format!("{:?}", out.to_str().unwrap()),
        )
        .replace(
            "\"profiles/jetson-nano-seed/",
            &format!("\"{}/", shipped.display()),
        );
    assert_ne!(config, reference);
    let config_path = dir.path().join("qos.toml");
    std::fs::write(&config_path, config).unwrap();
    let output = qosrt(&["plan", config_path.to_str().unwrap(), "--json"]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output));
    let plan: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let landing = plan["phases"]
        .as_array()
        .unwrap()
        .iter()
        .find(|p| p["phase"] == "landing" || p["name"] == "landing")
        .unwrap_or_else(|| panic!("no landing phase in {plan}"));
    let companion_w = landing["companion_power_w"].as_f64().unwrap();
    assert!((companion_w - vdd_in_w).abs() < 1e-6, "{landing}");

    // Run again: the measured profile is not overwritten without --force.
    let output = qosrt(&profile_args(
        root.to_str().unwrap(),
        out.to_str().unwrap(),
        &[],
    ));
    assert_eq!(output.status.code(), Some(2), "{}", text(&output));
    assert!(text(&output).contains("--force"));
}

#[test]
fn meters_are_listed_and_chosen_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let root = dir.path().join("root");
    fake_jetson(&root);
    let root = root.to_str().unwrap();
    let output = qosrt(&[
        "profile",
        "--list-meters",
        "--sysfs-root",
        root,
        "--nvml-library",
        "none",
    ]);
    let all = text(&output);
    assert_eq!(output.status.code(), Some(0), "{all}");
    assert!(
        all.contains("--meter jetson-ina3221-hwmon (the default)"),
        "{all}"
    );
    assert!(all.contains("pwmfan: no power"), "{all}");
    // A kind that is not here: refused, naming what is.
    let out = dir.path().join("p.toml");
    let output = qosrt(&profile_args(
        root,
        out.to_str().unwrap(),
        &["--meter", "rapl"],
    ));
    let all = text(&output);
    assert_eq!(output.status.code(), Some(3), "{all}");
    assert!(
        all.contains("no meter `rapl` here; found: jetson-ina3221-hwmon"),
        "{all}"
    );
}

#[test]
fn an_external_meters_log_is_merged_by_time() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("meter.csv");
    // A logger's file written ahead: 4.5 W every 50 ms for the next 20 s; rows count once
    // their time has come.
    let now_s = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_secs_f64();
    let mut rows = String::from("timestamp_s,power_w\n");
    for i in -20..400 {
        rows += &format!("{:.3},4.5\n", now_s + i as f64 * 0.05);
    }
    std::fs::write(&log, rows).unwrap();
    let out = dir.path().join("p.toml");
    let meter = format!("csv:{}", log.display());
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).unwrap();
    let output = qosrt(&profile_args(
        empty.to_str().unwrap(),
        out.to_str().unwrap(),
        &["--meter", &meter, "--board", "bench"],
    ));
    assert_eq!(output.status.code(), Some(0), "{}", text(&output));
    let profile = read_profile(&out);
    assert_eq!(profile.board, "bench");
    assert!(profile.meter.contains("meter.csv"), "{}", profile.meter);
    assert_eq!(profile.samples.len(), 2);
    for sample in &profile.samples {
        assert!((sample.power_w - 4.5).abs() < 1e-12, "{sample:?}");
    }
    // A log that does not exist is a meter error.
    let output = qosrt(&profile_args(
        empty.to_str().unwrap(),
        dir.path().join("q.toml").to_str().unwrap(),
        &["--meter", "csv:/nonexistent/meter.csv"],
    ));
    assert_eq!(output.status.code(), Some(3), "{}", text(&output));
    assert!(text(&output).contains("/nonexistent/meter.csv"));
}

#[test]
fn bad_arguments_are_refused_before_measuring() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("p.toml");
    let out = out.to_str().unwrap();
    for (extra, needle) in [
        (
            &["--phase", "landing", "--levels", "detection.rate_fps=3"][..],
            "not one of the task's levels [0.5, 1, 2, 10]",
        ),
        (
            &["--phase", "landing", "--levels", "hazard.rate_fps=1"][..],
            "no task that runs in phase `landing`",
        ),
        (&["--levels", "detection.rate_fps"][..], "TASK.KNOB=VALUE"),
        (&["--phase", "cruise"][..], "unknown phase `cruise`"),
        (&["--rate-hz", "0"][..], "--rate-hz"),
        (&["--duration-s=-1"][..], "--duration-s"),
        (&["--warmup-s", "nan"][..], "--warmup-s"),
    ] {
        let mut args = vec![
            "profile",
            "qos.toml",
            "--sysfs-root",
            "/nonexistent-root",
            "--out",
            out,
        ];
        args.extend_from_slice(extra);
        let output = qosrt(&args);
        let all = text(&output);
        assert_eq!(output.status.code(), Some(2), "{extra:?}: {all}");
        assert!(all.contains(needle), "{extra:?}: {all}");
    }
    assert!(!Path::new(out).exists());
}

/// `../shared/data/seed-jetson-nano`, or `None` (and a note) when absent.
fn seed_data() -> Option<PathBuf> {
    let dir = repo_root().join("../shared/data/seed-jetson-nano");
    if dir.is_dir() {
        Some(dir)
    } else {
        eprintln!(
            "SKIP: {} is absent, the test needs the seed's traces",
            dir.display()
        );
        None
    }
}

/// The first data row of a powprofiler grid, split by hand.
fn first_row(path: &Path) -> Vec<f64> {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .nth(1)
        .unwrap()
        .split(',')
        .map(|c| c.trim().parse().unwrap())
        .collect()
}

#[test]
fn from_csv_on_the_seeds_traces_reproduces_its_grid() {
    let Some(seed) = seed_data() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    for (trace, grid, point, knobs) in [
        (
            "1_Yolo4fps_nfold10fps.csv",
            "m2l_tracking.csv",
            "hazard.rate_fps=4,detection.rate_fps=10",
            2,
        ),
        (
            "1_nfold10fps.csv",
            "m2l_landing.csv",
            "detection.rate_fps=10",
            1,
        ),
    ] {
        let out = dir.path().join(format!("{grid}.toml"));
        let spec = format!("{point}:{}", seed.join(trace).display());
        let output = qosrt(&[
            "profile",
            "--from-csv",
            &spec,
            "--board",
            "jetson-nano",
            "--meter",
            "INA3221",
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(output.status.code(), Some(0), "{}", text(&output));
        let profile = read_profile(&out);
        assert_eq!(
            (profile.board.as_str(), profile.meter.as_str()),
            ("jetson-nano", "INA3221")
        );
        let sample = &profile.samples[0];
        // The grid's first row: knobs, then 100, 101, 102, 130 (the sum of the readings).
        let row = first_row(&seed.join(grid));
        assert_eq!(sample.knobs, row[..knobs]);
        let [total, cpu, gpu, sum] = [row[knobs], row[knobs + 1], row[knobs + 2], row[knobs + 3]];
        assert!(
            (sample.power_w - total).abs() < 1e-5,
            "{grid}: {} vs {total}",
            sample.power_w
        );
        assert!((sample.cpu_power_w.unwrap() - cpu).abs() < 1e-5, "{grid}");
        assert!((sample.gpu_power_w.unwrap() - gpu).abs() < 1e-5, "{grid}");
        let readings = (sum / total).round();
        assert!(
            (sample.duration_s.unwrap() - readings / 10.0).abs() < 1e-9,
            "{grid}"
        );
        assert!(sample.power_std_w.unwrap() > 0.0);
    }
}

#[test]
fn from_csv_bad_input_names_the_file_and_place() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.csv");
    std::fs::write(&good, "100,101\n3.0,1.0\n3.5,1.2\n").unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "100,101\n3.0,1.0\n3.5,x\n").unwrap();
    let out = dir.path().join("p.toml");
    let run = |specs: &[String]| {
        let mut args = vec![
            "profile".to_string(),
            "--out".into(),
            out.display().to_string(),
        ];
        for spec in specs {
            args.push("--from-csv".into());
            args.push(spec.clone());
        }
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        qosrt(&args)
    };
    let output = run(&[format!("a.rate_fps=1:{}", bad.display())]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("bad.csv:3:5: line 3, column 2: `x` is not a number"),
        "{}",
        text(&output)
    );
    let output = run(&[
        format!("a.rate_fps=1:{}", good.display()),
        format!("b.rate_fps=1:{}", good.display()),
    ]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output).contains("every trace needs a value for the same knobs"));
    let output = run(&[
        format!("a.rate_fps=1:{}", good.display()),
        format!("a.rate_fps=1:{}", good.display()),
    ]);
    assert_eq!(output.status.code(), Some(2));
    assert!(
        text(&output).contains("repeats the knob point"),
        "{}",
        text(&output)
    );
    let output = run(&[format!(
        "a.rate_fps=1:{}",
        dir.path().join("none.csv").display()
    )]);
    assert_eq!(output.status.code(), Some(2));
    assert!(text(&output).contains("cannot read"));
    // Good traces make a profile.
    let output = run(&[
        format!("a.rate_fps=1:{}", good.display()),
        format!("a.rate_fps=2:{}", good.display()),
    ]);
    assert_eq!(output.status.code(), Some(0), "{}", text(&output));
    let profile = read_profile(&out);
    assert_eq!(profile.samples[1].knobs, [2.0]);
    assert_eq!(profile.samples[1].power_w, 3.25);
}
