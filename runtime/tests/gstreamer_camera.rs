//! (feature `gstreamer`) The GStreamer camera source against real pipelines: `appsrc` fed by
//! the test, `videotestsrc`, and pipelines that cannot run.
#![cfg(feature = "gstreamer")]

use std::time::{Duration, Instant};

use gstreamer as gst;
use gstreamer::prelude::*;
use gstreamer_app as gst_app;
use runtime::camera::gstreamer::{GstreamerConfig, GstreamerSource};
use runtime::camera::{CameraSource, CameraSourceError, CameraStats, CapturedFrame};

/// A live appsrc of 30×24 grey frames: 30 is not a multiple of 4, so rows carry padding.
const WIDTH: usize = 30;
const HEIGHT: usize = 24;
const STRIDE: usize = 32;

fn appsrc_config() -> GstreamerConfig {
    GstreamerConfig::new(format!(
        "appsrc name=feed is-live=true do-timestamp=true format=time \
         caps=video/x-raw,format=GRAY8,width={WIDTH},height={HEIGHT},framerate=10/1"
    ))
}

fn feed(source: &GstreamerSource) -> gst_app::AppSrc {
    source
        .element("feed")
        .expect("the appsrc is in the pipeline")
        .downcast::<gst_app::AppSrc>()
        .unwrap()
}

/// Pushes one frame of uniform grey `level`, padding bytes 255 so a stride mistake shows.
fn push(feed: &gst_app::AppSrc, level: u8) {
    let mut bytes = vec![255u8; STRIDE * HEIGHT];
    for row in bytes.chunks_mut(STRIDE) {
        row[..WIDTH].fill(level);
    }
    feed.push_buffer(gst::Buffer::from_mut_slice(bytes))
        .unwrap();
}

/// Polls until `wanted` says stop or `limit` passes, on a clock that starts at 100 s.
fn poll_until(
    source: &mut GstreamerSource,
    limit: Duration,
    mut wanted: impl FnMut(f64, Result<Option<CapturedFrame>, CameraSourceError>) -> bool,
) {
    let start = Instant::now();
    while start.elapsed() < limit {
        let now_s = 100.0 + start.elapsed().as_secs_f64();
        if wanted(now_s, source.next_frame(now_s)) {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    panic!("nothing conclusive within {limit:?}");
}

#[test]
fn frames_arrive_whole_in_order_and_stamped_at_capture() {
    let mut source = GstreamerSource::open(GstreamerConfig {
        queue_frames: 16,
        ..appsrc_config()
    })
    .unwrap();
    let feed = feed(&source);
    let levels = [10u8, 60, 110, 160, 210];
    for level in levels {
        push(&feed, level);
    }
    feed.end_of_stream().unwrap();
    let mut frames = Vec::new();
    poll_until(
        &mut source,
        Duration::from_secs(10),
        |now_s, result| match result {
            Ok(Some(captured)) => {
                // Stamped at capture: not after now, and not long before.
                assert!(captured.capture_time_s <= now_s);
                assert!(captured.capture_time_s > now_s - 1.0);
                frames.push(captured.frame);
                false
            }
            Ok(None) => false,
            Err(CameraSourceError::Ended { .. }) => true,
            Err(other) => panic!("unexpected {other}"),
        },
    );
    let seen: Vec<(u64, u8)> = frames
        .iter()
        .map(|f| (f.frame_index, f.image.get(0, 0)))
        .collect();
    let wanted: Vec<(u64, u8)> = levels
        .iter()
        .enumerate()
        .map(|(i, &l)| (i as u64, l))
        .collect();
    assert_eq!(seen, wanted);
    for frame in &frames {
        assert_eq!((frame.image.width(), frame.image.height()), (WIDTH, HEIGHT));
        // The last column is the frame's, not the row padding's.
        assert_eq!(
            frame.image.get(WIDTH - 1, HEIGHT - 1),
            frame.image.get(0, 0)
        );
    }
    assert_eq!(
        source.stats(),
        CameraStats {
            delivered: 5,
            ..CameraStats::default()
        }
    );
}

#[test]
fn a_test_pattern_delivers_frames_of_its_size() {
    let mut source = GstreamerSource::open(GstreamerConfig {
        queue_frames: 64,
        ..GstreamerConfig::new(
            "videotestsrc num-buffers=8 pattern=ball ! video/x-raw,format=I420,width=64,height=48",
        )
    })
    .unwrap();
    let mut indices = Vec::new();
    poll_until(
        &mut source,
        Duration::from_secs(10),
        |_, result| match result {
            Ok(Some(captured)) => {
                let image = &captured.frame.image;
                assert_eq!((image.width(), image.height()), (64, 48));
                indices.push(captured.frame.frame_index);
                false
            }
            Ok(None) => false,
            Err(CameraSourceError::Ended { .. }) => true,
            Err(other) => panic!("unexpected {other}"),
        },
    );
    assert_eq!(indices, (0..8).collect::<Vec<u64>>());
}

#[test]
fn a_slow_reader_sees_the_newest_frames_and_the_drops_counted() {
    let mut source = GstreamerSource::open(appsrc_config()).unwrap();
    let feed = feed(&source);
    for level in [1, 2, 3, 4, 5] {
        push(&feed, level);
    }
    // The loop is late: the queue of two keeps the newest.
    std::thread::sleep(Duration::from_millis(500));
    let mut taken = Vec::new();
    while let Ok(Some(captured)) = source.next_frame(0.0) {
        taken.push((captured.frame.frame_index, captured.frame.image.get(0, 0)));
    }
    assert_eq!(taken, [(3, 4), (4, 5)]);
    let stats = source.stats();
    assert_eq!((stats.delivered, stats.dropped), (2, 3));
    // Half a second in the queue is late.
    assert_eq!(stats.late, 2);
}

#[test]
fn a_stalled_pipeline_is_named_once_per_stall() {
    let mut source = GstreamerSource::open(GstreamerConfig {
        first_frame_timeout_s: 0.3,
        stall_after_s: 0.3,
        ..appsrc_config()
    })
    .unwrap();
    let feed = feed(&source);
    let mut stalls = 0;
    let start = Instant::now();
    // Nothing comes: one stall, not one per poll.
    while start.elapsed() < Duration::from_millis(900) {
        match source.next_frame(0.0) {
            Err(CameraSourceError::Stalled { silent_s, .. }) => {
                assert!(silent_s >= 0.3);
                stalls += 1;
            }
            Ok(None) => {}
            other => panic!("unexpected {other:?}"),
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    assert_eq!(stalls, 1);
    // A frame ends the stall; silence again is a second one.
    push(&feed, 7);
    poll_until(&mut source, Duration::from_secs(5), |_, result| {
        matches!(result, Ok(Some(_)))
    });
    poll_until(
        &mut source,
        Duration::from_secs(5),
        |_, result| match result {
            Err(CameraSourceError::Stalled { .. }) => true,
            Ok(None) => false,
            other => panic!("unexpected {other:?}"),
        },
    );
    assert_eq!(source.stats().stalls, 2);
}

#[test]
fn frames_of_the_wrong_size_are_malformed_and_named() {
    let mut source = GstreamerSource::open(GstreamerConfig {
        expected_size_px: Some((640, 480)),
        ..appsrc_config()
    })
    .unwrap();
    push(&feed(&source), 9);
    poll_until(
        &mut source,
        Duration::from_secs(5),
        |_, result| match result {
            Err(CameraSourceError::Malformed {
                frame_index,
                problem,
                ..
            }) => {
                let reason = problem.to_string();
                assert_eq!(frame_index, 0);
                assert!(
                    reason.contains("30×24") && reason.contains("640×480"),
                    "{reason}"
                );
                true
            }
            Ok(None) => false,
            other => panic!("unexpected {other:?}"),
        },
    );
    assert_eq!(source.stats().malformed, 1);
}

#[test]
fn a_pipeline_that_cannot_run_is_a_named_error_not_a_hang() {
    match GstreamerSource::open(GstreamerConfig::new("nosuchelement_qosrt ! videoconvert")) {
        Err(CameraSourceError::Pipeline { reason, .. }) => {
            assert!(reason.contains("nosuchelement_qosrt"), "{reason}")
        }
        other => panic!("expected a pipeline error, got {other:?}"),
    }
    // A missing file fails once the pipeline starts: at open, or on the first polls.
    let started = Instant::now();
    let config = GstreamerConfig::new(
        "filesrc location=/nonexistent/qosrt/flight.mp4 ! decodebin ! videoconvert",
    );
    match GstreamerSource::open(config) {
        Err(CameraSourceError::Pipeline { reason, .. }) => {
            assert!(reason.contains("flight.mp4"), "{reason}")
        }
        Ok(mut source) => {
            poll_until(
                &mut source,
                Duration::from_secs(5),
                |_, result| match result {
                    Err(CameraSourceError::Pipeline { reason, .. }) => {
                        assert!(reason.contains("flight.mp4"), "{reason}");
                        true
                    }
                    Ok(None) => false,
                    other => panic!("unexpected {other:?}"),
                },
            );
            // And then it has ended.
            assert!(matches!(
                source.next_frame(0.0),
                Err(CameraSourceError::Ended { .. })
            ));
        }
        Err(other) => panic!("expected a pipeline error, got {other}"),
    }
    assert!(started.elapsed() < Duration::from_secs(5));
}
