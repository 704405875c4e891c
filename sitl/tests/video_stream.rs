//! (feature `gstreamer`) The simulator's camera over the network as Gazebo's is: frames
//! rendered by the simulator, encoded to RTP/H.264 and sent over UDP on localhost, come back
//! through `--camera rtp-h264:PORT`, and the landing-marker detector finds the pad in them
//! where it finds it in the raw frames, stamped with the capture time the sender wrote.
#![cfg(feature = "gstreamer")]

use std::net::UdpSocket;
use std::time::{Duration, Instant};

use algorithms::estimation::projection::Attitude;
use algorithms::vision::image::GrayImage;
use algorithms::vision::landing_marker::{LandingMarkerConfig, LandingMarkerDetector};
use nalgebra::Vector3;
use sim::camera::{SimCamera, SimCameraConfig, VehiclePose};
use sim::scene::{PadPose, SimScene, TractorBody};
use sitl::video_out::{RtpH264Sender, VideoStreamConfig};

/// A UDP port nobody holds right now.
fn free_port() -> u16 {
    UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn centre(detector: &mut LandingMarkerDetector, image: &GrayImage) -> Option<[f64; 2]> {
    detector
        .detect(&image.view(), None)
        .unwrap()
        .map(|o| o.centre_px)
}

#[test]
fn rendered_frames_survive_h264_over_udp_to_within_a_pixel() {
    const FRAMES: usize = 30;
    // Longer than any loopback delivery: a receiver that stamped at arrival would be this far
    // out at least.
    const CAPTURE_AGE: Duration = Duration::from_millis(40);
    let port = free_port();
    // The receiver first, as a companion waits for its camera.
    let mut camera_in = runtime::camera::open(&format!("rtp-h264:{port}"), None).unwrap();
    let config = SimCameraConfig::default();
    let mut sender = RtpH264Sender::open(VideoStreamConfig::new(
        port,
        config.width_px,
        config.height_px,
        config.rate_fps,
    ))
    .unwrap();
    let mut camera = SimCamera::new(config, 7).unwrap();
    let scene = SimScene::new(7)
        .with_tractor_body(TractorBody::default())
        .unwrap()
        .with_pad(PadPose {
            north_m: 0.0,
            east_m: 0.0,
            height_m: 1.0,
            yaw_rad: 0.3,
        })
        .unwrap();

    let start = Instant::now();
    // (image, when it was handed to the sender, its capture on the test's clock)
    let mut sent: Vec<(GrayImage, Instant, f64)> = Vec::new();
    // (image, arrival, capture time on the test's clock as the receiver stamped it)
    let mut received: Vec<(GrayImage, Instant, f64)> = Vec::new();
    let take = |camera_in: &mut Box<dyn runtime::camera::CameraSource>,
                received: &mut Vec<(GrayImage, Instant, f64)>| {
        let now_s = start.elapsed().as_secs_f64();
        loop {
            match camera_in.next_frame(now_s) {
                Ok(Some(captured)) => received.push((
                    (*captured.frame.image).clone(),
                    Instant::now(),
                    captured.capture_time_s,
                )),
                Ok(None) => break,
                // Once the sender is done, the stream falls silent: a stall, named.
                Err(runtime::camera::CameraSourceError::Stalled { .. })
                    if received.len() >= FRAMES - 3 =>
                {
                    break
                }
                Err(error) => panic!("after {} frames: {error}", received.len()),
            }
        }
    };
    for k in 0..FRAMES {
        // The vehicle drifts across the pad at 4–7 m, tilting a little.
        let t = k as f64 / FRAMES as f64;
        let pose = VehiclePose {
            position_ned_m: Vector3::new(-1.0 + 2.0 * t, 0.8 - 1.2 * t, -5.0 - 3.0 * t),
            attitude: Attitude::new(0.05 * (t * 6.0).sin(), -0.04, 0.2 + 0.3 * t),
            velocity_ned_m_s: Vector3::zeros(),
            body_rates_rad_s: Vector3::zeros(),
        };
        let time_s = k as f64 / 10.0;
        let frame = camera.capture_frame(time_s, &pose, &scene).unwrap();
        // The exposure happened CAPTURE_AGE before it is handed to the encoder.
        let captured = Instant::now();
        let captured_s = start.elapsed().as_secs_f64() - CAPTURE_AGE.as_secs_f64();
        sender.send(&frame.image, CAPTURE_AGE).unwrap();
        sent.push(((*frame.image).clone(), captured, captured_s));
        // At the camera's 10 fps, taking what has come back meanwhile.
        while start.elapsed() < Duration::from_millis(100 * (k as u64 + 1)) {
            take(&mut camera_in, &mut received);
            std::thread::sleep(Duration::from_millis(2));
        }
    }
    let drain_until = Instant::now() + Duration::from_secs(2);
    while Instant::now() < drain_until {
        take(&mut camera_in, &mut received);
        std::thread::sleep(Duration::from_millis(5));
    }
    assert!(
        received.len() >= FRAMES - 3,
        "{} of {FRAMES} frames came back",
        received.len()
    );

    let mut detector = LandingMarkerDetector::new(LandingMarkerConfig::default()).unwrap();
    let mut compared = 0;
    let mut worst_px: f64 = 0.0;
    let mut latencies_ms = Vec::new();
    let mut worst_stamp_error_ms: f64 = 0.0;
    for (image, arrived, capture_time_s) in &received {
        // The sent frame this one is: the closest in pixels (the poses differ frame to frame).
        let (index, difference) = sent
            .iter()
            .enumerate()
            .map(|(i, (raw, _, _))| (i, mean_abs_difference(raw, image)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        assert!(
            difference < 4.0,
            "frame {index}: {difference} grey levels apart"
        );
        latencies_ms.push((*arrived - sent[index].1).as_secs_f64() * 1e3);
        let stamp_error_ms = (capture_time_s - sent[index].2).abs() * 1e3;
        worst_stamp_error_ms = worst_stamp_error_ms.max(stamp_error_ms);
        let (Some(raw), Some(decoded)) = (
            centre(&mut detector, &sent[index].0),
            centre(&mut detector, image),
        ) else {
            panic!("frame {index}: the pad is not found in both the raw and the decoded frame");
        };
        let error_px = (raw[0] - decoded[0]).hypot(raw[1] - decoded[1]);
        worst_px = worst_px.max(error_px);
        compared += 1;
    }
    latencies_ms.sort_by(f64::total_cmp);
    let (wire_p50_ms, wire_p99_ms) = sender
        .latency_ms()
        .expect("the sender measured capture to wire");
    // Encoding 640×480 on this machine takes milliseconds, not frames.
    assert!(
        wire_p50_ms > 0.0 && wire_p50_ms < 100.0,
        "capture to wire {wire_p50_ms} ms"
    );
    eprintln!("capture to wire {wire_p50_ms:.1} ms median, {wire_p99_ms:.1} ms p99");
    eprintln!(
        "{compared} frames compared; worst centre difference {worst_px:.3} px; capture to \
         delivery {:.1} ms median, {:.1} ms max",
        latencies_ms[latencies_ms.len() / 2],
        latencies_ms[latencies_ms.len() - 1]
    );
    assert!(worst_px <= 1.0, "the pad moved {worst_px} px in H.264");
    // The sender's capture time came across the wire (RTP's NTP-64 header extension).
    let stats = camera_in.stats();
    assert_eq!(stats.sender_stamped, stats.delivered, "{stats:?}");
    assert_eq!(stats.sender_stamps_refused, 0, "{stats:?}");
    eprintln!("capture stamp within {worst_stamp_error_ms:.2} ms of the true capture");
    assert!(
        worst_stamp_error_ms < 3.0,
        "the received capture stamp is {worst_stamp_error_ms:.1} ms from the capture"
    );
}

fn mean_abs_difference(a: &GrayImage, b: &GrayImage) -> f64 {
    assert_eq!((a.width(), a.height()), (b.width(), b.height()));
    let total: u64 = a
        .data()
        .iter()
        .zip(b.data())
        .map(|(x, y)| u64::from(x.abs_diff(*y)))
        .sum();
    total as f64 / a.data().len() as f64
}
