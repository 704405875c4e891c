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

/// A TOML mistake keeps the TOML library's error as its cause; a mistake of our own has none.
#[test]
fn toml_errors_keep_the_librarys_error_as_their_cause() {
    let err = Profile::from_toml_str("board = \n").unwrap_err();
    let cause = std::error::Error::source(&err).expect("a cause");
    match cause.downcast_ref::<TomlError>() {
        Some(TomlError::Read(toml)) => assert_eq!(toml.message(), err.message),
        other => panic!("{other:?}"),
    }
    let err = Profile::from_toml_str(&GOOD.replace("power_w = 4\n", "power_w = -4\n")).unwrap_err();
    assert!(err.message.contains("power_w"), "{}", err.message);
    assert!(std::error::Error::source(&err).is_none());
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

const GRID_CSV: &str = "200,201,100,101,102,130\n4,10,6.0,2.0,1.9,6000\n4,0.5,6.3,2.1,2.0,6237\n";

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
