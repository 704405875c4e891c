//! `hazard-train`: renders a training set with the simulator, trains the hazard detector, writes
//! it as ONNX, scores it on held-out frames and writes the figures next to it as JSON.
//!
//! `cargo run --release -p hazard_train -- --out models/hazard_yolo.onnx`

use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::Instant;

use candle_core::Device;
use clap::Parser;
use hazard_train::dataset::{render_samples, CropConfig};
use hazard_train::evaluate::{evaluate, ClassCounts, Counts, OnnxDetector, Thresholds};
use hazard_train::model::{HazardNet, NetConfig, INPUT_HEIGHT_PX, INPUT_WIDTH_PX, STRIDE_PX};
use hazard_train::onnx_export::{self, ExportInfo, INPUT_NAME, OPSET, OUTPUT_NAME};
use hazard_train::target::LossWeights;
use hazard_train::train::{train, EpochReport, TrainConfig};
use serde_json::json;
use sim::scene::HazardClass;

/// Held-out frames start here; training frames are numbered from 0, so the two never meet.
const EVAL_SEED_BASE: u64 = 1 << 40;

#[derive(Debug, Parser)]
#[command(
    name = "hazard-train",
    about = "Train the hazard detector on simulated frames and export it as ONNX"
)]
struct Args {
    /// Where to write the model; the metrics go beside it with a .json extension.
    #[arg(long, default_value = "models/hazard_yolo.onnx")]
    out: PathBuf,
    /// Frames rendered for training (seeds 0 .. N).
    #[arg(long, default_value_t = 4000)]
    train_frames: u64,
    /// Held-out frames for the evaluation (seeds 2^40 ..).
    #[arg(long, default_value_t = 500)]
    eval_frames: u64,
    #[arg(long, default_value_t = 8)]
    epochs: usize,
    #[arg(long, default_value_t = 16)]
    batch_size: usize,
    /// Training crop, input pixels (multiples of 16; the input is 320×240).
    #[arg(long, default_value_t = 192)]
    crop_width_px: usize,
    #[arg(long, default_value_t = 192)]
    crop_height_px: usize,
    #[arg(long, default_value_t = 2e-3)]
    learning_rate: f64,
    /// Seeds the weights, the shuffling and the crops.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Threads for rendering and evaluation (candle uses its own pool, one per core).
    #[arg(long)]
    threads: Option<usize>,
    /// Only evaluate the model already at --out.
    #[arg(long)]
    evaluate_only: bool,
    #[arg(long, default_value_t = 0.5)]
    confidence: f64,
    #[arg(long, default_value_t = 0.45)]
    nms_iou: f64,
    #[arg(long, default_value_t = 0.5)]
    match_iou: f64,
}

fn main() -> ExitCode {
    keep_freed_memory();
    let args = Args::parse();
    match run(&args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(error) => {
            eprintln!("hazard-train: {error}");
            ExitCode::FAILURE
        }
    }
}

/// A file the tool could not write or create, with the I/O error.
#[derive(Debug, thiserror::Error)]
#[error("{action} {}: {source}", path.display())]
struct FileError {
    action: &'static str,
    path: std::path::PathBuf,
    #[source]
    source: std::io::Error,
}

type TrainResult<T> = Result<T, Box<dyn std::error::Error>>;

fn run(args: &Args) -> TrainResult<()> {
    let started = Instant::now();
    let threads = args.threads.unwrap_or_else(|| {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    });
    let thresholds = Thresholds {
        confidence: args.confidence,
        nms_iou: args.nms_iou,
        match_iou: args.match_iou,
    };
    let class_names: Vec<&str> = HazardClass::ALL.iter().map(|c| c.name()).collect();
    let json_path = args.out.with_extension("json");
    let training = if args.evaluate_only {
        // Re-scoring keeps what the earlier report says about how the model was trained.
        std::fs::read_to_string(&json_path)
            .ok()
            .and_then(|text| serde_json::from_str::<serde_json::Value>(&text).ok())
            .and_then(|report| report.get("training").cloned())
            .unwrap_or(serde_json::Value::Null)
    } else {
        train_and_export(args, threads, &class_names, started)?
    };

    println!(
        "evaluating {} on {} held-out frames (seeds from 2^40)…",
        args.out.display(),
        args.eval_frames
    );
    let detector = OnnxDetector::load(&args.out, INPUT_WIDTH_PX, INPUT_HEIGHT_PX)?;
    let eval_started = Instant::now();
    let evaluation = evaluate(
        &detector,
        EVAL_SEED_BASE..EVAL_SEED_BASE + args.eval_frames,
        &thresholds,
        threads,
    )?;
    println!(
        "evaluated in {:.1} s (confidence ≥ {}, NMS IoU {}, a match = same class and IoU ≥ {})",
        eval_started.elapsed().as_secs_f64(),
        thresholds.confidence,
        thresholds.nms_iou,
        thresholds.match_iou
    );
    print_table(
        &format!("all {} frames (4–12 m)", evaluation.frames),
        &evaluation.all,
        &class_names,
    );
    print_table(
        &format!("{} frames at 6–9 m", evaluation.typical_altitude_frames),
        &evaluation.typical_altitude,
        &class_names,
    );

    let model_bytes = std::fs::metadata(&args.out).map(|m| m.len()).unwrap_or(0);
    let report = json!({
        "model": args.out.file_name().map(|n| n.to_string_lossy().to_string()),
        "model_bytes": model_bytes,
        "opset": OPSET,
        "input": {
            "name": INPUT_NAME,
            "shape": [1, 1, INPUT_HEIGHT_PX, INPUT_WIDTH_PX],
            "preprocessing": "algorithms::vision::yolo::letterbox_gray(frame, 320, 240) of the 640×480 camera frame (scale 0.5, no padding), values in [0, 1]",
        },
        "output": {
            "name": OUTPUT_NAME,
            "shape": [1, (INPUT_HEIGHT_PX / STRIDE_PX) * (INPUT_WIDTH_PX / STRIDE_PX), 8],
            "layout": "YoloFormat::WithObjectness: [cx, cy, w, h, objectness, p_person, p_animal, p_vehicle], box in input pixels, scores after a sigmoid",
            "stride_px": STRIDE_PX,
        },
        "class_names": class_names,
        "thresholds": thresholds,
        "training": training,
        "evaluation": {
            "seeds": [EVAL_SEED_BASE, EVAL_SEED_BASE + args.eval_frames],
            "matching": "detections most confident first; a true positive overlaps an unmatched label of the same class by IoU ≥ match_iou",
            "all_frames": metrics_json(evaluation.frames, &evaluation.all, &class_names),
            "frames_6_to_9_m": metrics_json(evaluation.typical_altitude_frames, &evaluation.typical_altitude, &class_names),
        },
    });
    let text = serde_json::to_string_pretty(&report)?;
    std::fs::write(&json_path, text + "\n").map_err(|source| FileError {
        action: "writing",
        path: json_path.clone(),
        source,
    })?;
    println!(
        "wrote {} ({model_bytes} bytes) and {}; {:.1} s in all",
        args.out.display(),
        json_path.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// Renders, trains and writes the ONNX file; returns what the JSON says about the training.
fn train_and_export(
    args: &Args,
    threads: usize,
    class_names: &[&str],
    started: Instant,
) -> TrainResult<serde_json::Value> {
    let device = Device::Cpu;
    println!(
        "rendering {} training frames on {threads} threads…",
        args.train_frames
    );
    let render_started = Instant::now();
    let samples = render_samples(0..args.train_frames, threads, &|done| {
        println!("  {done} frames");
    })?;
    let labels: usize = samples.iter().map(|s| s.boxes.len()).sum();
    println!(
        "rendered {} frames with {labels} labels in {:.1} s",
        samples.len(),
        render_started.elapsed().as_secs_f64()
    );

    let net = HazardNet::new(NetConfig::standard(), args.seed, &device)?;
    let config = TrainConfig {
        epochs: args.epochs,
        batch_size: args.batch_size,
        crop: CropConfig {
            width_px: args.crop_width_px,
            height_px: args.crop_height_px,
            flips: true,
        },
        learning_rate: args.learning_rate,
        warmup_steps: 100,
        final_rate_fraction: 0.05,
        loss_weights: LossWeights::default(),
        seed: args.seed,
    };
    println!(
        "training {} parameters: {} epochs of {} steps, batches of {} {}×{} crops",
        net.parameter_count(),
        config.epochs,
        samples.len().div_ceil(config.batch_size),
        config.batch_size,
        config.crop.width_px,
        config.crop.height_px
    );
    let train_started = Instant::now();
    let reports = train(&net, &samples, &config, &device, &mut |r: &EpochReport| {
        println!(
            "  epoch {:>2}: loss {:.4} (objectness {:.4}, centre {:.4}, size {:.4}, class {:.4}), rate {:.2e}, {:.0} s",
            r.epoch + 1,
            r.loss,
            r.objectness,
            r.centre,
            r.size,
            r.class,
            r.learning_rate,
            r.seconds
        );
    })?;
    let train_s = train_started.elapsed().as_secs_f64();
    drop(samples);

    let info = ExportInfo {
        class_names,
        description: "qosrt hazard detector (person, animal, vehicle) trained on simulator frames by hazard_train",
    };
    let model = onnx_export::export(&net, INPUT_WIDTH_PX, INPUT_HEIGHT_PX, &info)?;
    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).map_err(|source| FileError {
            action: "creating",
            path: parent.to_path_buf(),
            source,
        })?;
    }
    let bytes = onnx_export::write(&model, &args.out)?;
    println!(
        "trained in {train_s:.0} s; wrote {} ({bytes} bytes)",
        args.out.display()
    );
    Ok(json!({
        "command": command_line(&args.out),
        "options": {
            "train_frames": args.train_frames,
            "train_seeds": [0, args.train_frames],
            "epochs": args.epochs,
            "batch_size": args.batch_size,
            "crop": config.crop,
            "learning_rate": args.learning_rate,
            "warmup_steps": config.warmup_steps,
            "final_rate_fraction": config.final_rate_fraction,
            "optimiser": "Adam (candle AdamW, weight decay 0)",
            "loss_weights": config.loss_weights,
            "seed": args.seed,
            "threads": threads,
        },
        "network": net.config,
        "parameters": net.parameter_count(),
        "epochs": reports,
        "train_seconds": train_s,
        "seconds_until_export": started.elapsed().as_secs_f64(),
    }))
}

/// Makes glibc's malloc serve blocks up to 32 MiB (its largest mmap threshold) from its heap and
/// keep freed memory: candle allocates every step's tensors afresh, and as separate mmaps their
/// page faults and unmaps took about 40 % of a training step on two cores.
fn keep_freed_memory() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt only changes allocator parameters; it is called before any other thread
    // exists, and both values are within the ranges glibc accepts.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
    }
}

/// The command that reproduces this run.
fn command_line(out: &Path) -> String {
    let rest: Vec<String> = std::env::args().skip(1).collect();
    let rest = if rest.is_empty() {
        format!("--out {}", out.display())
    } else {
        rest.join(" ")
    };
    format!("cargo run --release -p hazard_train -- {rest}")
}

fn print_table(title: &str, counts: &ClassCounts, class_names: &[&str]) {
    println!("{title}:");
    println!(
        "  {:<8} {:>9} {:>7} {:>5} {:>5} {:>6}",
        "class", "precision", "recall", "TP", "FP", "missed"
    );
    let row = |name: &str, c: &Counts| {
        println!(
            "  {:<8} {:>9.3} {:>7.3} {:>5} {:>5} {:>6}",
            name,
            c.precision(),
            c.recall(),
            c.true_positives,
            c.false_positives,
            c.misses
        );
    };
    for (name, c) in class_names.iter().zip(&counts.per_class) {
        row(name, c);
    }
    row("overall", &counts.overall());
}

fn metrics_json(frames: usize, counts: &ClassCounts, class_names: &[&str]) -> serde_json::Value {
    let one = |c: &Counts| {
        json!({
            "precision": c.precision(),
            "recall": c.recall(),
            "true_positives": c.true_positives,
            "false_positives": c.false_positives,
            "misses": c.misses,
        })
    };
    let per_class: serde_json::Map<String, serde_json::Value> = class_names
        .iter()
        .zip(&counts.per_class)
        .map(|(name, c)| (name.to_string(), one(c)))
        .collect();
    json!({
        "frames": frames,
        "per_class": per_class,
        "overall": one(&counts.overall()),
    })
}
