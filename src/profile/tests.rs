use super::*;

#[test]
fn from_csv_arguments() {
    let (point, path) = parse_from_csv("hazard.rate_fps=4,detection.rate_fps=0.5:a/b.csv").unwrap();
    assert_eq!(
        point,
        [
            ("hazard.rate_fps".to_string(), 4.0),
            ("detection.rate_fps".to_string(), 0.5)
        ]
    );
    assert_eq!(path, PathBuf::from("a/b.csv"));
    for (text, needle) in [
        ("trace.csv", "expected KNOB=VALUE"),
        ("a.b=1:", "no file"),
        ("a.b:x.csv", "is not KNOB=VALUE"),
        ("a.b=x:x.csv", "`x` is not a number"),
        ("a.b=1,a.b=2:x.csv", "given twice"),
    ] {
        let error = parse_from_csv(text).unwrap_err();
        assert!(error.contains(needle), "{text}: {error}");
    }
}

#[test]
fn slugs() {
    assert_eq!(
        slug("NVIDIA Jetson Nano Developer Kit"),
        "nvidia-jetson-nano-developer-kit"
    );
    assert_eq!(slug("  a__b  "), "a-b");
}
