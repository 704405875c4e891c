//! Arguments several subcommands share: recording and the live view, `--fix`, `N,E`.

use runtime::config::MissionConfig;
use runtime::record::{FrameCodec, FramePolicy, RecorderOptions};
use std::net::SocketAddr;
use std::path::PathBuf;

/// Recording, the live view and ROS 2, for `qosrt sim` and `qosrt run`.
#[derive(clap::Args, Debug, Clone, Default)]
pub struct RecordArgs {
    /// Record the mission to this MCAP file (frames, telemetry, every topic and decision, the
    /// config): open it in Foxglove, or re-run it with `qosrt replay`.
    #[arg(long, value_name = "FILE.mcap")]
    pub record: Option<PathBuf>,
    /// Serve the same channels live over Foxglove's WebSocket protocol (default address
    /// 127.0.0.1:8765; in Foxglove: Open connection → Foxglove WebSocket → ws://ADDR).
    #[arg(long, value_name = "ADDR", num_args = 0..=1, require_equals = true, default_missing_value = "127.0.0.1:8765")]
    pub foxglove: Option<SocketAddr>,
    /// Which camera frames the recording (and the live view) keeps, losslessly: every
    /// (the default; the whole mission replays), consumed (only the frames a task read; the
    /// whole mission still replays) or none (telemetry, decisions and outputs: a few MB a
    /// minute; the tasks that read frames cannot be replayed).
    /// (Default: the config's `[record] frames`, else every.)
    #[arg(long, value_name = "every|consumed|none")]
    pub record_frames: Option<FramePolicy>,
    /// How kept frames are stored, all lossless: compact (qosrt's codec, the smallest: about
    /// 0.48 of the raw frames), png (about 0.56; Foxglove shows the file's frames) or raw. The
    /// live view gets PNGs either way. (Default: the config's `[record] codec`, else compact.)
    #[arg(long, value_name = "compact|png|raw")]
    pub record_codec: Option<FrameCodec>,
    /// Each recording file's size budget in MB: a file ends at a step of the loop before it
    /// passes it, and the recording goes on in FILE-1.mcap, FILE-2.mcap, … (`qosrt replay
    /// FILE.mcap` follows them). (Default: the config's `[record] max_mb`, else no budget.)
    #[arg(long, value_name = "MB", value_parser = clap::value_parser!(u64).range(1..))]
    pub record_max_mb: Option<u64>,
    /// Publish the mission on ROS 2 (DDS, domain 0) under /qosrt/VEHICLE/: pose, battery,
    /// velocity setpoint, phase, governor decisions, task diagnostics. `qosrt sim` then flies
    /// on the wall clock, as a flight does.
    #[arg(long, value_name = "VEHICLE", num_args = 0..=1, require_equals = true, default_missing_value = "vehicle_1")]
    pub ros2: Option<String>,
}

impl RecordArgs {
    /// Where to record, if anywhere, and what: the flags, else the mission's `[record]`.
    pub fn options(&self, config: &MissionConfig) -> Option<RecorderOptions> {
        let configured = config.record.unwrap_or_default();
        (self.record.is_some() || self.foxglove.is_some()).then(|| RecorderOptions {
            file: self.record.clone(),
            live: self.foxglove,
            frames: self.record_frames.unwrap_or(configured.frames),
            codec: self.record_codec.unwrap_or(configured.codec),
            max_bytes: self
                .record_max_mb
                .or(configured.max_mb.map(u64::from))
                .map(|mb| mb * 1_000_000),
            ..RecorderOptions::default()
        })
    }
}

/// `TASK=VALUE` for `--fix`.
pub fn parse_fixed_level(text: &str) -> Result<(String, f64), String> {
    let (task, value) = text
        .split_once('=')
        .ok_or_else(|| format!("expected TASK=VALUE (e.g. detection=10), found `{text}`"))?;
    let value: f64 = value
        .trim()
        .parse()
        .map_err(|_| format!("`{value}` is not a number; expected TASK=VALUE"))?;
    if task.trim().is_empty() {
        return Err(format!("no task name in `{text}`; expected TASK=VALUE"));
    }
    Ok((task.trim().to_string(), value))
}

/// `N,E` in metres, e.g. `15,0`.
pub fn parse_north_east(text: &str) -> Result<[f64; 2], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let [north, east] = parts[..] else {
        return Err(format!(
            "expected N,E in metres (e.g. 15,0), found {text:?}"
        ));
    };
    let number = |part: &str| {
        part.trim()
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{part:?} is not a number of metres"))
    };
    Ok([number(north)?, number(east)?])
}
