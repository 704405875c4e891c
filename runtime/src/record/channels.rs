//! The recording's channels: each topic's name, encoding, schema and role, and the pure
//! conversions between the runtime's values and the bytes a channel carries.
//!
//! Foxglove's well-known schemas (protobuf) serve where one fits, so the file opens in Foxglove
//! with no plugin: the camera (`foxglove.RawImage`), the marker and hazard boxes
//! (`foxglove.ImageAnnotations`), the vehicle's pose (`foxglove.PoseInFrame`,
//! `foxglove.FrameTransform`) and the mission's events (`foxglove.Log`). qosrt's own messages
//! are JSON, each channel with a JSON schema naming its type.

use crate::link::Incoming;
use crate::topics::{HazardReport, MarkerObservation, VehicleState};
use algorithms::vision::image::{DepthImage, FrameError, GrayImage};
use foxglove::messages as fg;
use mavlink::dialects::common::MavMessage;
use mavlink::{MavHeader, Message as _};
use prost::Message as _;
use serde::{Deserialize, Serialize};

/// What a replay does with a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The loop's clock: one message per step of the mission runner.
    Clock,
    /// What the runtime was given (telemetry, frames): a replay feeds it again.
    Input,
    /// What the runtime made of it (bus topics, commands, decisions): a replay compares it.
    Output,
    /// Measurements of the machine (task timings): kept, never compared.
    Info,
}

/// How a channel's messages are encoded.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    Json,
    /// A Foxglove well-known schema: the schema comes from the Foxglove SDK.
    Foxglove(FoxgloveSchema),
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FoxgloveSchema {
    RawImage,
    CompressedImage,
    ImageAnnotations,
    PoseInFrame,
    FrameTransform,
    Log,
}

/// One channel of a recording.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ChannelSpec {
    pub topic: &'static str,
    /// The JSON schema's name (qosrt's own messages); unused for Foxglove's.
    pub type_name: &'static str,
    pub encoding: Encoding,
    pub role: Role,
}

impl ChannelSpec {
    const fn json(topic: &'static str, type_name: &'static str, role: Role) -> Self {
        Self {
            topic,
            type_name,
            encoding: Encoding::Json,
            role,
        }
    }

    const fn foxglove(topic: &'static str, schema: FoxgloveSchema, role: Role) -> Self {
        Self {
            topic,
            type_name: "",
            encoding: Encoding::Foxglove(schema),
            role,
        }
    }

    /// The MCAP message encoding.
    pub fn message_encoding(&self) -> &'static str {
        match self.encoding {
            Encoding::Json => "json",
            Encoding::Foxglove(_) => "protobuf",
        }
    }

    /// The schema: its name, encoding and data.
    pub fn schema(&self) -> foxglove::Schema {
        use foxglove::Encode;
        let schema = match self.encoding {
            Encoding::Json => {
                return foxglove::Schema::new(
                    self.type_name,
                    "jsonschema",
                    format!(r#"{{"title":"{}","type":"object"}}"#, self.type_name).into_bytes(),
                )
            }
            Encoding::Foxglove(FoxgloveSchema::RawImage) => fg::RawImage::get_schema(),
            Encoding::Foxglove(FoxgloveSchema::CompressedImage) => {
                fg::CompressedImage::get_schema()
            }
            Encoding::Foxglove(FoxgloveSchema::ImageAnnotations) => {
                fg::ImageAnnotations::get_schema()
            }
            Encoding::Foxglove(FoxgloveSchema::PoseInFrame) => fg::PoseInFrame::get_schema(),
            Encoding::Foxglove(FoxgloveSchema::FrameTransform) => fg::FrameTransform::get_schema(),
            Encoding::Foxglove(FoxgloveSchema::Log) => fg::Log::get_schema(),
        };
        schema.expect("Foxglove's well-known messages have schemas")
    }
}

pub const STEP: ChannelSpec = ChannelSpec::json("/qosrt/step", "qosrt.Step", Role::Clock);
pub const MAVLINK_IN: ChannelSpec =
    ChannelSpec::json("/mavlink/in", "qosrt.MavlinkBatch", Role::Input);
/// Each frame kept, as a PNG ([`super::frames`]; recordings before it: `foxglove.RawImage`).
pub const CAMERA_IMAGE: ChannelSpec = ChannelSpec::foxglove(
    "/camera/image",
    FoxgloveSchema::CompressedImage,
    Role::Input,
);
/// Each frame no task read, by its size alone (`frames = "consumed"`).
pub const CAMERA_UNREAD: ChannelSpec =
    ChannelSpec::json("/camera/unread", "qosrt.UnreadFrame", Role::Input);
pub const CAMERA_DEPTH: ChannelSpec =
    ChannelSpec::foxglove("/camera/depth", FoxgloveSchema::RawImage, Role::Input);
/// Each plan change asked for in flight (a ground station's), as the runner took it: before the
/// step it was taken in, so a replay hands it to the same step.
pub const PLAN_REQUEST: ChannelSpec =
    ChannelSpec::json("/qosrt/plan_request", "qosrt.PlanRequest", Role::Input);
pub const MAVLINK_OUT: ChannelSpec =
    ChannelSpec::json("/mavlink/out", "qosrt.MavlinkMessage", Role::Output);
pub const GOVERNOR: ChannelSpec =
    ChannelSpec::json("/qosrt/governor", "qosrt.GovernorDecision", Role::Output);
pub const QOS_LEVELS: ChannelSpec =
    ChannelSpec::json("/qosrt/qos_levels", "qosrt.QosLevels", Role::Output);
pub const BATTERY: ChannelSpec =
    ChannelSpec::json("/qosrt/battery", "qosrt.BatteryEstimate", Role::Output);
pub const EVENTS: ChannelSpec =
    ChannelSpec::foxglove("/qosrt/events", FoxgloveSchema::Log, Role::Output);
pub const ANNOTATIONS: ChannelSpec = ChannelSpec::foxglove(
    "/camera/annotations",
    FoxgloveSchema::ImageAnnotations,
    Role::Output,
);
pub const VEHICLE_POSE: ChannelSpec =
    ChannelSpec::foxglove("/vehicle/pose", FoxgloveSchema::PoseInFrame, Role::Output);
pub const VEHICLE_TF: ChannelSpec =
    ChannelSpec::foxglove("/tf", FoxgloveSchema::FrameTransform, Role::Output);
pub const TASK_STATS: ChannelSpec =
    ChannelSpec::json("/qosrt/task_stats", "qosrt.TaskStats", Role::Info);

/// The bus topics a recording keeps, each as `/bus/<topic>`: every message published on them.
pub const BUS_TOPICS: [ChannelSpec; 7] = [
    ChannelSpec::json("/bus/vehicle/state", "qosrt.VehicleState", Role::Output),
    ChannelSpec::json("/bus/mission/phase", "qosrt.MissionPhase", Role::Output),
    ChannelSpec::json(
        "/bus/vision/landing_marker",
        "qosrt.MarkerObservation",
        Role::Output,
    ),
    ChannelSpec::json(
        "/bus/tracking/relative_state",
        "qosrt.RelativeState",
        Role::Output,
    ),
    ChannelSpec::json(
        "/bus/landing/setpoint",
        "qosrt.LandingSetpoint",
        Role::Output,
    ),
    ChannelSpec::json("/bus/vision/hazards", "qosrt.HazardReport", Role::Output),
    ChannelSpec::json(
        "/bus/tracking/hybrid_status",
        "qosrt.HybridTrackingStatus",
        Role::Output,
    ),
];

/// Every channel a recording may hold.
pub fn all_channels() -> Vec<ChannelSpec> {
    let mut channels = vec![
        STEP,
        MAVLINK_IN,
        CAMERA_IMAGE,
        CAMERA_UNREAD,
        CAMERA_DEPTH,
        MAVLINK_OUT,
        GOVERNOR,
        QOS_LEVELS,
        BATTERY,
        EVENTS,
        ANNOTATIONS,
        VEHICLE_POSE,
        VEHICLE_TF,
        TASK_STATS,
    ];
    channels.extend(BUS_TOPICS);
    channels
}

/// The channel of `topic`, if a recording may hold it.
pub fn channel(topic: &str) -> Option<ChannelSpec> {
    all_channels().into_iter().find(|c| c.topic == topic)
}

/// One step of the mission runner.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct StepRecord {
    pub now_s: f64,
    /// The simulated autopilot's lockstep tick, in a lockstep simulation.
    pub lockstep_ns: Option<u64>,
}

/// One batch the link received, its messages as MAVLink 2 frames (hex).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MavlinkBatch {
    pub frames: Vec<String>,
    pub malformed: bool,
    pub unsigned: usize,
    /// When the link took the batch (recordings before it was kept have none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub received_s: Option<f64>,
}

/// One message the link sent.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct MavlinkRecord {
    pub name: String,
    pub frame: String,
}

/// A MAVLink 2 frame of `message`, as hex.
pub fn mavlink_frame_hex(header: &MavHeader, message: &MavMessage) -> String {
    let mut bytes = Vec::with_capacity(64);
    // Writing into a Vec cannot fail.
    let _ = mavlink::write_v2_msg(&mut bytes, *header, message);
    hex::encode(bytes)
}

impl MavlinkBatch {
    pub fn from_incoming(incoming: &Incoming) -> Self {
        Self {
            frames: incoming
                .messages
                .iter()
                .map(|(header, message)| mavlink_frame_hex(header, message))
                .collect(),
            malformed: incoming.malformed,
            unsigned: incoming.unsigned,
            received_s: incoming.received_s,
        }
    }

    /// The batch as the link received it; a frame that does not decode is named.
    pub fn to_incoming(&self) -> Result<Incoming, ChannelError> {
        let messages = self
            .frames
            .iter()
            .enumerate()
            .map(|(index, frame)| decode_frame_hex(index, frame))
            .collect::<Result<_, _>>()?;
        Ok(Incoming {
            messages,
            malformed: self.malformed,
            unsigned: self.unsigned,
            from: None,
            received_s: self.received_s,
        })
    }
}

impl MavlinkRecord {
    pub fn new(header: &MavHeader, message: &MavMessage) -> Self {
        Self {
            name: message.message_name().to_string(),
            frame: mavlink_frame_hex(header, message),
        }
    }

    /// The message as the link sent it; a frame that does not decode is named.
    pub fn message(&self) -> Result<(MavHeader, MavMessage), ChannelError> {
        decode_frame_hex(0, &self.frame)
    }
}

/// One MAVLink 2 frame from its hex (frame `index` of its batch, for the error).
fn decode_frame_hex(index: usize, frame: &str) -> Result<(MavHeader, MavMessage), ChannelError> {
    let bytes = hex::decode(frame).map_err(|source| ChannelError::Hex { index, source })?;
    let decoded = crate::link::connection::decode_datagram(&bytes);
    let [message] = <[_; 1]>::try_from(decoded).map_err(|decoded| ChannelError::MessageCount {
        index,
        found: decoded.len(),
    })?;
    Ok(message)
}

/// Foxglove's timestamp of a time in nanoseconds.
pub fn timestamp(time_ns: u64) -> fg::Timestamp {
    fg::Timestamp::new(
        (time_ns / 1_000_000_000) as u32,
        (time_ns % 1_000_000_000) as u32,
    )
}

/// A grayscale frame as `foxglove.RawImage` (mono8), stamped at its capture.
pub fn gray_image(image: &GrayImage, capture_ns: u64) -> Vec<u8> {
    fg::RawImage {
        timestamp: Some(timestamp(capture_ns)),
        frame_id: "camera".into(),
        width: image.width() as u32,
        height: image.height() as u32,
        encoding: "mono8".into(),
        step: image.width() as u32,
        data: image.data().to_vec().into(),
    }
    .encode_to_vec()
}

/// A depth frame as `foxglove.RawImage` (32FC1, metres, little-endian).
pub fn depth_image(image: &DepthImage, capture_ns: u64) -> Vec<u8> {
    let data: Vec<u8> = image
        .data()
        .iter()
        .flat_map(|depth| depth.to_le_bytes())
        .collect();
    fg::RawImage {
        timestamp: Some(timestamp(capture_ns)),
        frame_id: "camera".into(),
        width: image.width() as u32,
        height: image.height() as u32,
        encoding: "32FC1".into(),
        step: 4 * image.width() as u32,
        data: data.into(),
    }
    .encode_to_vec()
}

/// Why a recorded message does not decode.
#[derive(Debug, thiserror::Error)]
pub enum ChannelError {
    #[error("frame {index}: {source}")]
    Hex {
        index: usize,
        #[source]
        source: hex::FromHexError,
    },
    #[error("frame {index}: expected one MAVLink message, found {found}")]
    MessageCount { index: usize, found: usize },
    #[error("not a foxglove.RawImage: {0}")]
    NotRawImage(#[source] prost::DecodeError),
    #[error("not a foxglove.CompressedImage: {0}")]
    NotCompressedImage(#[source] prost::DecodeError),
    #[error("expected a frame as an 8-bit grey {expected}, found {found}")]
    ImageFormat {
        expected: &'static str,
        found: String,
    },
    #[error("the frame's png does not decode: {0}")]
    Png(#[from] image::ImageError),
    #[error("the frame's compact codec does not decode: {0}")]
    Compact(#[from] super::gray_codec::GrayCodecError),
    #[error(
        "expected a packed {expected} image, found {found} with step {step} for width {width}"
    )]
    ImageLayout {
        expected: &'static str,
        found: String,
        step: u32,
        width: u32,
    },
    #[error(transparent)]
    Image(#[from] FrameError),
}

/// A decoded `foxglove.RawImage`.
fn raw_image(
    bytes: &[u8],
    encoding: &'static str,
    bytes_per_pixel: u32,
) -> Result<fg::RawImage, ChannelError> {
    let image = fg::RawImage::decode(bytes).map_err(ChannelError::NotRawImage)?;
    if image.encoding != encoding || image.step != bytes_per_pixel * image.width {
        return Err(ChannelError::ImageLayout {
            expected: encoding,
            found: image.encoding,
            step: image.step,
            width: image.width,
        });
    }
    Ok(image)
}

/// The grayscale frame a `foxglove.RawImage` holds.
pub fn decode_gray_image(bytes: &[u8]) -> Result<GrayImage, ChannelError> {
    let image = raw_image(bytes, "mono8", 1)?;
    GrayImage::from_vec(
        image.width as usize,
        image.height as usize,
        image.data.to_vec(),
    )
    .map_err(ChannelError::Image)
}

/// The depth frame a `foxglove.RawImage` holds.
pub fn decode_depth_image(bytes: &[u8]) -> Result<DepthImage, ChannelError> {
    let image = raw_image(bytes, "32FC1", 4)?;
    let depth_m = image
        .data
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    DepthImage::from_vec(image.width as usize, image.height as usize, depth_m)
        .map_err(ChannelError::Image)
}

/// A mission event as `foxglove.Log`.
pub fn log_message(time_ns: u64, text: &str) -> Vec<u8> {
    fg::Log {
        timestamp: Some(timestamp(time_ns)),
        level: fg::log::Level::Info as i32,
        message: text.to_string(),
        name: "qosrt".into(),
        file: String::new(),
        line: 0,
    }
    .encode_to_vec()
}

/// The vehicle's pose in the local NED frame (`foxglove.PoseInFrame`) and as the transform
/// `ned` → `vehicle` (`foxglove.FrameTransform`); `None` without a position.
pub fn vehicle_pose(time_ns: u64, state: &VehicleState) -> Option<(Vec<u8>, Vec<u8>)> {
    let position = state.position_ned_m?;
    let q = nalgebra::UnitQuaternion::from_euler_angles(
        state.attitude.roll_rad,
        state.attitude.pitch_rad,
        state.attitude.yaw_rad,
    );
    let translation = fg::Vector3 {
        x: position.x,
        y: position.y,
        z: position.z,
    };
    let rotation = fg::Quaternion {
        x: q.i,
        y: q.j,
        z: q.k,
        w: q.w,
    };
    let pose = fg::PoseInFrame {
        timestamp: Some(timestamp(time_ns)),
        frame_id: "ned".into(),
        pose: Some(fg::Pose {
            position: Some(translation),
            orientation: Some(rotation),
        }),
    };
    let transform = fg::FrameTransform {
        timestamp: Some(timestamp(time_ns)),
        parent_frame_id: "ned".into(),
        child_frame_id: "vehicle".into(),
        translation: Some(translation),
        rotation: Some(rotation),
    };
    Some((pose.encode_to_vec(), transform.encode_to_vec()))
}

const MARKER_COLOUR: fg::Color = fg::Color {
    r: 0.1,
    g: 0.9,
    b: 0.2,
    a: 1.0,
};
const HAZARD_COLOUR: fg::Color = fg::Color {
    r: 1.0,
    g: 0.3,
    b: 0.1,
    a: 1.0,
};

/// The pad the detector found, as a circle and a label on the camera image.
pub fn marker_annotations(capture_ns: u64, marker: &MarkerObservation) -> Vec<u8> {
    let stamp = Some(timestamp(capture_ns));
    let mut annotations = fg::ImageAnnotations {
        timestamp: stamp,
        ..Default::default()
    };
    if let Some(seen) = &marker.observation {
        let [u, v] = seen.centre_px;
        let diameter = seen.pad_size_px.unwrap_or(40.0);
        annotations.circles.push(fg::CircleAnnotation {
            timestamp: stamp,
            position: Some(fg::Point2 { x: u, y: v }),
            diameter,
            thickness: 2.0,
            fill_color: None,
            outline_color: Some(MARKER_COLOUR),
            metadata: Vec::new(),
        });
        annotations.texts.push(text(
            stamp,
            u,
            v - diameter / 2.0,
            "pad".into(),
            MARKER_COLOUR,
        ));
    }
    annotations.encode_to_vec()
}

/// The hazards the CNN saw, as labelled boxes on the camera image.
pub fn hazard_annotations(report: &HazardReport) -> Vec<u8> {
    let stamp = Some(timestamp((report.capture_time_s.max(0.0) * 1e9) as u64));
    let mut annotations = fg::ImageAnnotations {
        timestamp: stamp,
        ..Default::default()
    };
    for detection in &report.detections {
        let b = &detection.bbox;
        let corners = [
            (b.x_min, b.y_min),
            (b.x_max, b.y_min),
            (b.x_max, b.y_max),
            (b.x_min, b.y_max),
        ];
        annotations.points.push(fg::PointsAnnotation {
            timestamp: stamp,
            r#type: fg::points_annotation::Type::LineLoop as i32,
            points: corners.iter().map(|&(x, y)| fg::Point2 { x, y }).collect(),
            outline_color: Some(HAZARD_COLOUR),
            outline_colors: Vec::new(),
            fill_color: None,
            thickness: 2.0,
            metadata: Vec::new(),
        });
        let label = format!(
            "{} {:.0} %",
            detection.class_name,
            100.0 * detection.confidence
        );
        annotations
            .texts
            .push(text(stamp, b.x_min, b.y_min, label, HAZARD_COLOUR));
    }
    annotations.encode_to_vec()
}

fn text(
    stamp: Option<fg::Timestamp>,
    x: f64,
    y: f64,
    text: String,
    colour: fg::Color,
) -> fg::TextAnnotation {
    fg::TextAnnotation {
        timestamp: stamp,
        position: Some(fg::Point2 { x, y }),
        text,
        font_size: 14.0,
        text_color: Some(colour),
        background_color: None,
        metadata: Vec::new(),
    }
}

/// A message as JSON (a value of the runtime's own types: serialising cannot fail).
pub fn json<T: Serialize + ?Sized>(value: &T) -> Vec<u8> {
    serde_json::to_vec(value).expect("the runtime's messages serialise to JSON")
}

#[cfg(test)]
mod tests {
    use super::*;
    use mavlink::dialects::common::ATTITUDE_DATA;

    #[test]
    fn a_mavlink_batch_comes_back_as_it_was_received() {
        let header = MavHeader {
            system_id: 1,
            component_id: 1,
            sequence: 42,
        };
        let attitude = MavMessage::ATTITUDE(ATTITUDE_DATA {
            time_boot_ms: 1234,
            roll: 0.1,
            pitch: -0.2,
            yaw: f32::NAN,
            ..Default::default()
        });
        let incoming = Incoming {
            messages: vec![(header, attitude)],
            malformed: false,
            unsigned: 2,
            from: None,
            received_s: Some(12.345_678_9),
        };
        let batch = MavlinkBatch::from_incoming(&incoming);
        let json = serde_json::to_string(&batch).unwrap();
        let back: MavlinkBatch = serde_json::from_str(&json).unwrap();
        let decoded = back.to_incoming().unwrap();
        assert_eq!(decoded.unsigned, 2);
        assert_eq!(decoded.received_s, Some(12.345_678_9));
        let (got_header, MavMessage::ATTITUDE(got)) = &decoded.messages[0] else {
            panic!("not an ATTITUDE: {decoded:?}");
        };
        assert_eq!(got_header.sequence, 42);
        assert_eq!((got.time_boot_ms, got.roll, got.pitch), (1234, 0.1, -0.2));
        // NaN survives as bits, which JSON numbers could not carry.
        assert!(got.yaw.is_nan());
    }

    #[test]
    fn a_frame_that_is_not_mavlink_is_named() {
        let batch = MavlinkBatch {
            frames: vec!["fd01".into(), "zz".into()],
            malformed: false,
            unsigned: 0,
            received_s: None,
        };
        let error = batch.to_incoming().unwrap_err();
        assert!(error.to_string().starts_with("frame 0:"), "{error}");
    }

    #[test]
    fn images_come_back_pixel_for_pixel() {
        let pixels: Vec<u8> = (0..12 * 7).map(|i| (i * 37 % 251) as u8).collect();
        let gray = GrayImage::from_vec(12, 7, pixels.clone()).unwrap();
        let back = decode_gray_image(&gray_image(&gray, 5)).unwrap();
        assert_eq!((back.width(), back.height()), (12, 7));
        assert_eq!(back.data(), &pixels[..]);
        let depths: Vec<f32> = (0..6).map(|i| i as f32 * 0.7).chain([f32::NAN]).collect();
        let depth = DepthImage::from_vec(7, 1, depths.clone()).unwrap();
        let back = decode_depth_image(&depth_image(&depth, 5)).unwrap();
        let bits = |d: &[f32]| d.iter().map(|v| v.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(back.data()), bits(&depths));
        // A depth frame is not a grayscale one.
        assert!(decode_gray_image(&depth_image(&depth, 5)).is_err());
    }
}
