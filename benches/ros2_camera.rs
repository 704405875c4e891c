//! How long a frame a ROS 2 camera driver publishes takes to reach qosrt's mission loop
//! (`--camera ros2:/TOPIC`), the queue the loop hands the detector its frames from, against the
//! reference DDS reader on the same stream in the same run.
//!
//! A camera driver (Cyclone DDS's Python binding, its own process) publishes 640×480 mono8
//! `sensor_msgs/Image` frames at 30 fps, each stamped just before it is published. qosrt's
//! ROS 2 camera reads them as a mission does, woken by each arrival, and so does a second
//! process with Cyclone DDS's own reader (the baseline), one after the other. For every
//! frame: its arrival less its stamp. The ratio is qosrt's p99 over the baseline's; the goal is qosrt's p99 ≤ 5 ms.
//!
//! A frame larger than the kernel's socket receive buffer is lost whole when its fragments
//! overflow it: RustDDS keeps the default (`net.core.rmem_default`, 208 KB on many Linux
//! hosts, less than a 307 KB frame). Such losses are counted (`lost on the way`); raise it
//! (`sysctl -w net.core.rmem_default=4194304`) for a camera of this size.
//!
//! `cargo bench --bench ros2_camera` (needs Python 3; installs Cyclone DDS's binding from PyPI
//! under `target/` once, as the ROS 2 tests do, and says so and stops where it cannot).

#[path = "../tests/common/mod.rs"]
mod common;

use std::path::Path;
use std::process::{Child, Stdio};
use std::time::{Duration, Instant};

const WIDTH: usize = 640;
const HEIGHT: usize = 480;
const FPS: f64 = 30.0;
const SECONDS: f64 = 30.0;
/// The longest wait for the two sides to find each other (DDS discovery).
const DISCOVERY_LIMIT_S: f64 = 60.0;

fn percentile(sorted: &[f64], fraction: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * fraction).round() as usize]
}

/// The driver publishing on `topic` for `seconds`.
fn publisher(python: &Path, topic: &str, seconds: f64) -> Child {
    common::cyclone_script(python, "publish_camera.py")
        .args([topic, &seconds.to_string()])
        .args([WIDTH.to_string(), HEIGHT.to_string(), FPS.to_string()])
        .spawn()
        .expect("the publisher starts")
}

/// qosrt's ROS 2 camera reading the driver: each frame's delay from its stamp until the loop
/// takes it, over the first SECONDS of frames.
fn qosrt_delays_ms(python: &Path) -> Vec<f64> {
    let topic = format!("/bench_{}/qosrt/image_raw", std::process::id());
    let mut camera =
        runtime::camera::open(&format!("ros2:{topic}"), Some((WIDTH, HEIGHT))).expect("camera");
    let mut driver = publisher(python, &topic, DISCOVERY_LIMIT_S + SECONDS);
    camera.wake_on_frame(std::thread::current());
    let start = Instant::now();
    let mut delays_ms = Vec::new();
    let mut first_s = None;
    while start.elapsed() < Duration::from_secs_f64(DISCOVERY_LIMIT_S + SECONDS) {
        let now_s = start.elapsed().as_secs_f64();
        match camera.next_frame(now_s) {
            Ok(Some(frame)) => {
                // Timed from the first frame on, once discovery is over.
                let first = *first_s.get_or_insert(now_s);
                if now_s - first >= SECONDS {
                    break;
                }
                // Taken by the loop: what a task is handed next.
                delays_ms.push((now_s - frame.capture_time_s) * 1e3);
            }
            // Parked until the source's thread says a frame came, as the mission loop is.
            Ok(None) => std::thread::park_timeout(Duration::from_millis(50)),
            Err(error) => eprintln!("frame refused: {error}"),
        }
    }
    let _ = driver.kill();
    let _ = driver.wait();
    let stats = camera.stats();
    println!(
        "  qosrt's camera: {} delivered, {} lost on the way, {} dropped by its queue, {} malformed",
        stats.delivered, stats.lost_in_transport, stats.dropped, stats.malformed
    );
    delays_ms
}

/// Cyclone DDS's reader (its own process) on the same driver, over as many frames.
fn baseline_delays_ms(python: &Path, frames: usize) -> Vec<f64> {
    let topic = format!("/bench_{}/cyclone/image_raw", std::process::id());
    let reader = common::cyclone_script(python, "receive_camera.py")
        .args([&topic, &frames.to_string()])
        .arg((DISCOVERY_LIMIT_S + SECONDS).to_string())
        .stdout(Stdio::piped())
        .spawn()
        .expect("the baseline reader starts");
    let mut driver = publisher(python, &topic, DISCOVERY_LIMIT_S + SECONDS);
    let output = reader.wait_with_output().expect("the baseline's delays");
    let _ = driver.kill();
    let _ = driver.wait();
    serde_json::from_slice(&output.stdout).expect("a JSON list")
}

fn main() {
    let Some(python) = common::cyclonedds_python() else {
        return;
    };
    // One after the other, so that neither reader takes the cores from the other.
    let mut delays_ms = qosrt_delays_ms(&python);
    let mut baseline_ms = baseline_delays_ms(&python, delays_ms.len());
    for delays in [&mut delays_ms, &mut baseline_ms] {
        delays.sort_by(f64::total_cmp);
    }
    if delays_ms.is_empty() || baseline_ms.is_empty() {
        eprintln!(
            "no frames: qosrt {} and the baseline {}",
            delays_ms.len(),
            baseline_ms.len()
        );
        std::process::exit(1);
    }
    println!("ROS 2 camera, {WIDTH}×{HEIGHT} mono8 at {FPS} fps, stamp to arrival (ms):");
    for (name, delays) in [
        ("qosrt (RustDDS)", &delays_ms),
        ("Cyclone DDS (baseline)", &baseline_ms),
    ] {
        println!(
            "  {name:<24} frames {:>5}  p50 {:>6.2}  p99 {:>6.2}  max {:>6.2}",
            delays.len(),
            percentile(delays, 0.5),
            percentile(delays, 0.99),
            delays[delays.len() - 1]
        );
    }
    println!(
        "  p99 ratio qosrt / baseline: {:.2}",
        percentile(&delays_ms, 0.99) / percentile(&baseline_ms, 0.99)
    );
}
