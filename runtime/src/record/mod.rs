//! Recording a mission to MCAP, reading it back, and serving it live to Foxglove.
//!
//! A recording holds what the runtime was given (the loop's clock, the MAVLink it received, the
//! camera frames it delivered, the depth frames a simulator published) and what it made of it
//! (every recorded bus topic, the MAVLink it sent, governor decisions, QoS levels, battery,
//! mission events), with the config files it flew as attachments and a header saying how to
//! fly it again. `mission::replay` re-runs the tasks on the inputs and compares the outputs.

pub mod channels;
mod encoded;
mod frame_hold;
pub mod frames;
pub mod gray_codec;
pub mod latency;
pub mod reader;
pub mod recorder;
mod sink;

pub use crate::config::{FrameCodec, FramePolicy};
pub use reader::{
    read_recording, read_recording_file, RecordedMessage, Recording, RecordingReader,
};
pub use recorder::{Recorder, RecorderOptions, RecordingSummary};
pub use sink::part_path;

use crate::config::{MissionConfig, MissionPlan};
use serde::{Deserialize, Serialize};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};

/// The name of the MCAP metadata record holding the [`RecordingHeader`].
pub const HEADER_METADATA: &str = "qosrt";
/// The name of the metadata record that ends a part of a split recording, naming the next.
pub const CONTINUES_METADATA: &str = "qosrt.continues";
/// The recording format this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;

/// What can go wrong while recording or reading a recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("cannot create the recording {path}: {source}")]
    Create {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot read {path}: {source}")]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot read the config file {path} to record it: {source}")]
    ConfigFile {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("MCAP: {0}")]
    Mcap(#[source] mcap::McapError),
    #[error("recording: {0}")]
    Io(#[source] std::io::Error),
    #[error("cannot serve Foxglove's WebSocket on {address}: {source}")]
    Live {
        address: SocketAddr,
        #[source]
        source: Box<foxglove::FoxgloveError>,
    },
    #[error("cannot start the recorder's thread: {0}")]
    Thread(#[source] std::io::Error),
    #[error("the recorder's thread panicked; the file may end early")]
    WriterPanicked,
    #[error("not a qosrt recording: {0}")]
    NotARecording(String),
    #[error(
        "the recorded config names {path} by an absolute path and this machine has no identical \
         copy there: replay with --config"
    )]
    AbsoluteConfigPath { path: PathBuf },
}

/// Where a recorded mission came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordingSource {
    /// `qosrt sim`: the built-in world, in lockstep on the virtual clock.
    Sim,
    /// `qosrt run`: a real (or SITL) autopilot on the wall clock.
    Flight,
}

/// How the recorded mission was flown: what a replay needs beside the config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct RecordingHeader {
    pub format_version: u32,
    pub qosrt_version: String,
    pub source: RecordingSource,
    /// The scheduler's seed (tasks that draw random numbers).
    pub seed: u64,
    pub plan: MissionPlan,
    /// Every phase's duration as flown (a simulation may override the config's).
    pub phase_durations_s: Vec<f64>,
    /// The runner's `--fix` levels and LANDING_TARGET setting (its options; the runner's
    /// caller sets them after `new`).
    pub fixed_levels: Vec<(String, f64)>,
    pub landing_target: bool,
    /// The runner had a camera.
    pub camera: bool,
    /// The config's name among the recording's attachments.
    pub config_file: String,
    /// The link had somewhere to send from the start (udpout, TCP, serial); udpin learns it
    /// from the autopilot's first message.
    pub link_peer_known: bool,
    /// Which frames the recording kept (recordings from before the policy kept every one).
    #[serde(default)]
    pub frames: FramePolicy,
    /// How the kept frames are stored (recordings from before compression: raw).
    #[serde(default = "FrameCodec::before_compression")]
    pub frame_codec: FrameCodec,
    /// The recording's own id: every part of a split recording carries it.
    #[serde(default)]
    pub recording_id: String,
    /// Which part of a recording split by its size budget this file is: 0, the first (or
    /// the only one).
    #[serde(default)]
    pub part: u32,
    /// In a later part: the first part's file name, and the time of the step it follows.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_part: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub part_starts_ns: Option<u64>,
}

impl RecordingHeader {
    pub fn new(
        source: RecordingSource,
        seed: u64,
        plan: MissionPlan,
        config: &MissionConfig,
        camera: bool,
        config_file: String,
    ) -> Self {
        Self {
            format_version: FORMAT_VERSION,
            qosrt_version: env!("CARGO_PKG_VERSION").into(),
            source,
            seed,
            plan,
            phase_durations_s: config.mission.phases.iter().map(|p| p.duration_s).collect(),
            fixed_levels: Vec::new(),
            landing_target: false,
            camera,
            config_file,
            link_peer_known: false,
            frames: FramePolicy::Every,
            frame_codec: FrameCodec::default(),
            recording_id: String::new(),
            part: 0,
            first_part: None,
            part_starts_ns: None,
        }
    }
}

/// A file the mission's config consists of, by its path relative to the config's folder.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigFile {
    pub path: String,
    pub data: Vec<u8>,
}

impl ConfigFile {
    /// The config file and the power profiles it names, read from disk.
    pub fn collect(config_path: &Path, config: &MissionConfig) -> Result<Vec<Self>, RecordError> {
        let read = |path: &Path| {
            std::fs::read(path).map_err(|source| RecordError::ConfigFile {
                path: path.to_path_buf(),
                source,
            })
        };
        let base = config_path.parent().unwrap_or(Path::new(""));
        let name = config_path
            .file_name()
            .map_or("qos.toml".into(), |n| n.to_string_lossy().into_owned());
        let mut files = vec![Self {
            path: name,
            data: read(config_path)?,
        }];
        for profile in &config.power_model.profiles {
            files.push(Self {
                path: profile.path.clone(),
                data: read(&base.join(&profile.path))?,
            });
        }
        Ok(files)
    }
}

/// Writes a recording's config files under `dir` as they lay beside each other, and returns
/// the config's path there. A profile outside the config's folder (`../x.toml`) keeps its
/// place: the config goes as many folders deep as the deepest such path climbs. A profile named
/// by an absolute path is used where it is, if an identical copy is there.
pub fn extract_config(
    files: &[ConfigFile],
    config_file: &str,
    dir: &Path,
) -> Result<PathBuf, RecordError> {
    let climbs = |path: &str| {
        Path::new(path)
            .components()
            .take_while(|c| matches!(c, std::path::Component::ParentDir))
            .count()
    };
    let depth = files
        .iter()
        .filter(|f| !Path::new(&f.path).is_absolute())
        .map(|f| climbs(&f.path))
        .max()
        .unwrap_or(0);
    let mut base = dir.to_path_buf();
    for level in 0..depth {
        base.push(format!("d{level}"));
    }
    let io = |path: &Path| {
        let path = path.to_path_buf();
        move |source| RecordError::ConfigFile { path, source }
    };
    for file in files {
        let relative = Path::new(&file.path);
        if relative.is_absolute() {
            if std::fs::read(relative).ok().as_deref() != Some(&file.data[..]) {
                return Err(RecordError::AbsoluteConfigPath {
                    path: relative.to_path_buf(),
                });
            }
            continue;
        }
        if relative
            .components()
            .skip(climbs(&file.path))
            .any(|c| matches!(c, std::path::Component::ParentDir))
        {
            return Err(RecordError::NotARecording(format!(
                "its config file {:?} is not a relative path",
                file.path
            )));
        }
        let path = base.join(relative);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent).map_err(io(parent))?;
        }
        std::fs::write(&path, &file.data).map_err(io(&path))?;
    }
    Ok(base.join(config_file))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn extracted_config_files_lie_beside_each_other_as_recorded() {
        let dir = tempfile::tempdir().unwrap();
        let files = [
            ConfigFile {
                path: "qos.toml".into(),
                data: b"config".to_vec(),
            },
            ConfigFile {
                path: "profiles/board/landing.toml".into(),
                data: b"landing".to_vec(),
            },
            ConfigFile {
                path: "../../shared/tracking.toml".into(),
                data: b"tracking".to_vec(),
            },
        ];
        let config = extract_config(&files, "qos.toml", dir.path()).unwrap();
        assert_eq!(std::fs::read(&config).unwrap(), b"config");
        let base = config.parent().unwrap();
        assert_eq!(
            std::fs::read(base.join("profiles/board/landing.toml")).unwrap(),
            b"landing"
        );
        assert_eq!(
            std::fs::read(base.join("../../shared/tracking.toml")).unwrap(),
            b"tracking"
        );
        // Nothing is written outside the folder it was given.
        assert!(base
            .join("../../shared/tracking.toml")
            .canonicalize()
            .unwrap()
            .starts_with(dir.path().canonicalize().unwrap()));
        let escaping = [ConfigFile {
            path: "profiles/../../x.toml".into(),
            data: Vec::new(),
        }];
        assert!(matches!(
            extract_config(&escaping, "qos.toml", dir.path()),
            Err(RecordError::NotARecording(_))
        ));
        // An absolute path is used where it is when the file there is the recorded one.
        let here = dir.path().join("board.toml");
        std::fs::write(&here, b"measured").unwrap();
        let absolute = |data: &[u8]| {
            [ConfigFile {
                path: here.to_string_lossy().into_owned(),
                data: data.to_vec(),
            }]
        };
        assert!(extract_config(&absolute(b"measured"), "qos.toml", dir.path()).is_ok());
        assert!(matches!(
            extract_config(&absolute(b"another board"), "qos.toml", dir.path()),
            Err(RecordError::AbsoluteConfigPath { .. })
        ));
    }
}
