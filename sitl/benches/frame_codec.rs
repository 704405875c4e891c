//! The recording's frame codecs on the simulated camera's frames: a short mission (tracking
//! 10 s) is flown and recorded with raw frames, then every frame is encoded and decoded by the
//! compact codec and by PNG (the baseline) in the same run, alternately, on one thread. It
//! prints each codec's share of the raw bytes and its encode and decode time per frame, and
//! the ratios to PNG.
//!
//! `cargo bench -p sitl --bench frame_codec`

use runtime::catalog::PluginCatalog;
use runtime::config::load_file;
use runtime::energy::load_mission_model;
use runtime::plugins::builtin_registry;
use runtime::record::frames::{decode_frame, encode_frame};
use runtime::record::{read_recording_file, FrameCodec, RecorderOptions};
use sitl::mission::{simulate, SimOptions, SimRecording};
use std::path::Path;
use std::time::Instant;

const REPEATS: usize = 5;

fn main() {
    let registry = builtin_registry().expect("the built-in plugins register");
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../qos.toml");
    let loaded = load_file(&path, &PluginCatalog::builtin()).expect("the reference config");
    let model = load_mission_model(&loaded).expect("the reference power model");
    let file = std::env::temp_dir().join(format!("qosrt-codec-bench-{}.mcap", std::process::id()));
    let options = SimOptions {
        tracking_s: Some(10.0),
        record: Some(SimRecording {
            recorder: RecorderOptions {
                file: Some(file.clone()),
                codec: FrameCodec::Raw,
                ..RecorderOptions::default()
            },
            config_files: Vec::new(),
        }),
        ..SimOptions::default()
    };
    simulate(&model, &registry, &options).expect("the mission flies");
    let recording = read_recording_file(&file).expect("the recording reads back");
    let _ = std::fs::remove_file(&file);
    let frames: Vec<_> = recording
        .topic("/camera/image")
        .map(|m| decode_frame(FrameCodec::Raw, &m.data).expect("a raw frame"))
        .collect();
    let raw_bytes: usize = frames.iter().map(|f| f.data().len()).sum();
    println!(
        "{} frames of {}×{}",
        frames.len(),
        frames[0].width(),
        frames[0].height()
    );
    let codecs = [FrameCodec::Png, FrameCodec::Compact];
    // Per codec: bytes, and the best-of-repeats encode and decode seconds for all frames.
    let mut results = [(0usize, f64::MAX, f64::MAX); 2];
    for _ in 0..REPEATS {
        for (codec, result) in codecs.iter().zip(&mut results) {
            let start = Instant::now();
            let encoded: Vec<Vec<u8>> = frames.iter().map(|f| encode_frame(*codec, f, 0)).collect();
            let encode_s = start.elapsed().as_secs_f64();
            let start = Instant::now();
            for (bytes, frame) in encoded.iter().zip(&frames) {
                let back = decode_frame(*codec, bytes).expect("its own frame decodes");
                assert_eq!(back.data(), frame.data(), "lossless");
            }
            let decode_s = start.elapsed().as_secs_f64();
            result.0 = encoded.iter().map(Vec::len).sum();
            result.1 = result.1.min(encode_s);
            result.2 = result.2.min(decode_s);
        }
    }
    let per_frame_ms = |s: f64| s * 1e3 / frames.len() as f64;
    let png = results[0];
    for (codec, (bytes, encode_s, decode_s)) in codecs.iter().zip(results) {
        println!(
            "{:<8} {:.3} of the raw bytes, encode {:.2} ms, decode {:.2} ms a frame \
             (size x{:.3}, encode x{:.2}, decode x{:.2} of PNG; best of {REPEATS})",
            format!("{codec:?}"),
            bytes as f64 / raw_bytes as f64,
            per_frame_ms(encode_s),
            per_frame_ms(decode_s),
            bytes as f64 / png.0 as f64,
            encode_s / png.1,
            decode_s / png.2,
        );
    }
}
