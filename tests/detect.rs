//! End-to-end tests of `qosrt detect` on rendered frames written as image files.

mod common;
use common::qosrt;

use algorithms::camera::{CameraPose, PinholeCamera};
use algorithms::vision::landing_marker::LandingMarkerLayout;
use algorithms::vision::render::{render, true_pixel, RenderOptions, Scene, Texture};
use nalgebra::Vector3;
use std::path::{Path, PathBuf};

/// Renders the reference pad 3 m below a slightly tilted camera into `path`; returns the true
/// pixel of the pad's centre.
fn write_pad_frame(path: &Path) -> [f64; 2] {
    let camera = PinholeCamera::from_fov(640, 480, 60f64.to_radians()).unwrap();
    let pose = CameraPose::downward(Vector3::new(0.0, 0.0, -3.0), 0.08, -0.05, 0.7);
    let mut scene = Scene::new(Texture::field(21));
    scene.patches = LandingMarkerLayout::default()
        .patches(0.2, -0.3, 0.0, 2.0)
        .unwrap();
    let frame = render(&camera, &pose, &scene, &RenderOptions::default()).unwrap();
    image::GrayImage::from_raw(640, 480, frame.data().to_vec())
        .unwrap()
        .save(path)
        .unwrap();
    let centre = true_pixel(&camera, &pose, &scene.patches[0].point_world(0.0, 0.0)).unwrap();
    [centre.0, centre.1]
}

#[test]
fn detect_finds_the_pad_and_its_markers_in_an_image_file() {
    let dir = tempfile::tempdir().unwrap();
    let frame = dir.path().join("pad.png");
    let truth = write_pad_frame(&frame);
    let output = qosrt(&["detect", "--json", frame.to_str().unwrap()]);
    assert_eq!(
        output.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&output.stderr)
    );
    let reports: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    let report = &reports[0];
    assert_eq!(report["width_px"], 640);
    let mut ids: Vec<u64> = report["aruco"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_u64().unwrap())
        .collect();
    ids.sort();
    assert_eq!(ids, [1, 2, 3]);
    let centre = &report["landing_marker"]["centre_px"];
    let error =
        (centre[0].as_f64().unwrap() - truth[0]).hypot(centre[1].as_f64().unwrap() - truth[1]);
    assert!(error < 0.5, "centre error {error} px");
    let nfold = &report["nfold"]["centre_px"];
    let error =
        (nfold[0].as_f64().unwrap() - truth[0]).hypot(nfold[1].as_f64().unwrap() - truth[1]);
    assert!(error < 0.5, "n-fold error {error} px");
}

#[test]
fn a_file_that_is_not_an_image_is_reported_and_the_others_still_read() {
    let dir = tempfile::tempdir().unwrap();
    let good: PathBuf = dir.path().join("pad.png");
    write_pad_frame(&good);
    let bad = dir.path().join("notes.png");
    std::fs::write(&bad, "not an image").unwrap();
    let output = qosrt(&[
        "detect",
        "--json",
        bad.to_str().unwrap(),
        good.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    let reports: serde_json::Value = serde_json::from_slice(&output.stdout).unwrap();
    assert!(reports[0]["error"]
        .as_str()
        .unwrap()
        .contains("not a readable image"));
    assert!(reports[1]["landing_marker"].is_object());
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(stderr.contains("notes.png"), "{stderr}");
}

#[test]
fn a_bad_layout_file_is_located() {
    let dir = tempfile::tempdir().unwrap();
    let layout = dir.path().join("layout.toml");
    std::fs::write(&layout, "pad_size_m = 1.0\nnfold_order = \"four\"\n").unwrap();
    let frame = dir.path().join("pad.png");
    write_pad_frame(&frame);
    let output = qosrt(&[
        "detect",
        "--layout",
        layout.to_str().unwrap(),
        frame.to_str().unwrap(),
    ]);
    assert_eq!(output.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert!(
        stderr.contains(&format!("{}:2:15:", layout.display())),
        "{stderr}"
    );
}
