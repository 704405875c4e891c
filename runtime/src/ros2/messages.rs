//! ROS 2's standard message types, field for field as their `.msg` files declare them, so that
//! their CDR encoding is what `rclcpp`, `rclpy` and `ros2 topic echo` expect; and the
//! conversions from the runtime's values, in ROS's frames (REP 103: `map` is east-north-up, the
//! vehicle's `base_link` forward-left-up).

use crate::telemetry::BatteryTelemetry;
use crate::topics::VehicleState;
use nalgebra::{UnitQuaternion, Vector3};
use serde::{Deserialize, Serialize};

/// `builtin_interfaces/Time`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Time {
    pub sec: i32,
    pub nanosec: u32,
}

impl Time {
    /// The runtime's clock, in seconds since the mission began (a flight's companion clock).
    pub fn from_secs(time_s: f64) -> Self {
        let time_s = time_s.max(0.0);
        let sec = time_s.floor();
        Self {
            sec: sec as i32,
            nanosec: (((time_s - sec) * 1e9).round() as u32).min(999_999_999),
        }
    }

    pub fn as_secs(&self) -> f64 {
        f64::from(self.sec) + f64::from(self.nanosec) * 1e-9
    }
}

/// `std_msgs/Header`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct Header {
    pub stamp: Time,
    pub frame_id: String,
}

impl Header {
    pub fn at(time_s: f64, frame_id: &str) -> Self {
        Self {
            stamp: Time::from_secs(time_s),
            frame_id: frame_id.into(),
        }
    }
}

/// `std_msgs/String`.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct StringMessage {
    pub data: String,
}

/// `geometry_msgs/Point` and `geometry_msgs/Vector3` (the same layout).
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Point {
    pub x: f64,
    pub y: f64,
    pub z: f64,
}

/// `geometry_msgs/Quaternion`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Quaternion {
    pub x: f64,
    pub y: f64,
    pub z: f64,
    pub w: f64,
}

/// `geometry_msgs/Pose`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Pose {
    pub position: Point,
    pub orientation: Quaternion,
}

/// `geometry_msgs/PoseStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PoseStamped {
    pub header: Header,
    pub pose: Pose,
}

/// `geometry_msgs/Twist`.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize, Deserialize)]
pub struct Twist {
    pub linear: Point,
    pub angular: Point,
}

/// `geometry_msgs/TwistStamped`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TwistStamped {
    pub header: Header,
    pub twist: Twist,
}

/// `sensor_msgs/BatteryState`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct BatteryState {
    pub header: Header,
    pub voltage: f32,
    pub temperature: f32,
    pub current: f32,
    pub charge: f32,
    pub capacity: f32,
    pub design_capacity: f32,
    pub percentage: f32,
    pub power_supply_status: u8,
    pub power_supply_health: u8,
    pub power_supply_technology: u8,
    pub present: bool,
    pub cell_voltage: Vec<f32>,
    pub cell_temperature: Vec<f32>,
    pub location: String,
    pub serial_number: String,
}

/// `POWER_SUPPLY_STATUS_DISCHARGING`, `POWER_SUPPLY_HEALTH_UNKNOWN`,
/// `POWER_SUPPLY_TECHNOLOGY_LIPO`.
const DISCHARGING: u8 = 2;
const HEALTH_UNKNOWN: u8 = 0;
const LIPO: u8 = 3;

impl BatteryState {
    /// The autopilot's battery reading; what it does not report is NaN, as the message asks.
    /// ROS's current is negative while discharging; MAVLink's is positive out of the pack.
    pub fn from_telemetry(telemetry: &BatteryTelemetry, design_capacity_ah: f64) -> Self {
        let known = |value: Option<f64>| value.map_or(f32::NAN, |v| v as f32);
        Self {
            header: Header::at(telemetry.time_s, ""),
            voltage: known(telemetry.voltage_v),
            temperature: f32::NAN,
            current: known(telemetry.current_a.map(|a| -a)),
            charge: known(
                telemetry
                    .consumed_mah
                    .map(|mah| design_capacity_ah - mah / 1e3),
            ),
            capacity: f32::NAN,
            design_capacity: design_capacity_ah as f32,
            percentage: known(telemetry.remaining_fraction),
            power_supply_status: DISCHARGING,
            power_supply_health: HEALTH_UNKNOWN,
            power_supply_technology: LIPO,
            present: true,
            cell_voltage: Vec::new(),
            cell_temperature: Vec::new(),
            location: String::new(),
            serial_number: String::new(),
        }
    }
}

/// `diagnostic_msgs/KeyValue`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct KeyValue {
    pub key: String,
    pub value: String,
}

/// `diagnostic_msgs/DiagnosticStatus` (`level` is a `byte`: 0 OK, 1 WARN, 2 ERROR, 3 STALE).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticStatus {
    pub level: u8,
    pub name: String,
    pub message: String,
    pub hardware_id: String,
    pub values: Vec<KeyValue>,
}

/// `diagnostic_msgs/DiagnosticArray`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DiagnosticArray {
    pub header: Header,
    pub status: Vec<DiagnosticStatus>,
}

/// `sensor_msgs/Image`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Image {
    pub header: Header,
    pub height: u32,
    pub width: u32,
    pub encoding: String,
    pub is_bigendian: u8,
    pub step: u32,
    pub data: Vec<u8>,
}

/// `sensor_msgs/CompressedImage` (`format` as image_transport writes it: `jpeg`, `png`, or
/// `rgb8; jpeg compressed bgr8`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CompressedImage {
    pub header: Header,
    pub format: String,
    pub data: Vec<u8>,
}

/// `vision_msgs/Point2D`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Point2D {
    pub x: f64,
    pub y: f64,
}

/// `vision_msgs/Pose2D`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Pose2D {
    pub position: Point2D,
    pub theta: f64,
}

/// `vision_msgs/BoundingBox2D`: the box's centre and size, in pixels.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct BoundingBox2D {
    pub center: Pose2D,
    pub size_x: f64,
    pub size_y: f64,
}

/// `vision_msgs/ObjectHypothesis`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectHypothesis {
    pub class_id: String,
    pub score: f64,
}

/// `geometry_msgs/PoseWithCovariance`'s `float64[36]`: a fixed array, no length on the wire.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Covariance(pub [f64; 36]);

impl Serialize for Covariance {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeTuple;
        let mut tuple = serializer.serialize_tuple(36)?;
        for value in &self.0 {
            tuple.serialize_element(value)?;
        }
        tuple.end()
    }
}

/// `geometry_msgs/PoseWithCovariance`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct PoseWithCovariance {
    pub pose: Pose,
    pub covariance: Covariance,
}

/// `vision_msgs/ObjectHypothesisWithPose`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ObjectHypothesisWithPose {
    pub hypothesis: ObjectHypothesis,
    pub pose: PoseWithCovariance,
}

/// `vision_msgs/Detection2D`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Detection2D {
    pub header: Header,
    pub results: Vec<ObjectHypothesisWithPose>,
    pub bbox: BoundingBox2D,
    pub id: String,
}

/// `vision_msgs/Detection2DArray`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Detection2DArray {
    pub header: Header,
    pub detections: Vec<Detection2D>,
}

const IDENTITY: Quaternion = Quaternion {
    x: 0.0,
    y: 0.0,
    z: 0.0,
    w: 1.0,
};

/// A hazard report as `vision_msgs/Detection2DArray`, stamped at the frame's capture: each
/// box in the frame's pixels, its class and confidence, and where it lies on the ground in
/// `map` (ENU; the origin where that is not known), its covariance unknown (`-1` first, as ROS
/// marks it).
pub fn hazard_detections(report: &crate::topics::HazardReport) -> Detection2DArray {
    let header = Header::at(report.capture_time_s, "camera");
    let mut unknown = [0.0; 36];
    unknown[0] = -1.0;
    let detections = report
        .detections
        .iter()
        .enumerate()
        .map(|(index, detection)| {
            let bbox = &detection.bbox;
            Detection2D {
                header: header.clone(),
                results: vec![ObjectHypothesisWithPose {
                    hypothesis: ObjectHypothesis {
                        class_id: detection.class_name.to_string(),
                        score: detection.confidence,
                    },
                    pose: PoseWithCovariance {
                        pose: Pose {
                            position: detection
                                .position_ned_m
                                .as_ref()
                                .map_or(Point::default(), enu),
                            orientation: IDENTITY,
                        },
                        covariance: Covariance(unknown),
                    },
                }],
                bbox: BoundingBox2D {
                    center: Pose2D {
                        position: Point2D {
                            x: (bbox.x_min + bbox.x_max) / 2.0,
                            y: (bbox.y_min + bbox.y_max) / 2.0,
                        },
                        theta: 0.0,
                    },
                    size_x: bbox.x_max - bbox.x_min,
                    size_y: bbox.y_max - bbox.y_min,
                },
                id: format!("{}/{index}", report.frame_index),
            }
        })
        .collect();
    Detection2DArray { header, detections }
}

/// The pad in `map` (ENU) where the tracker puts it: the vehicle's position less its estimate
/// of the vehicle relative to the pad.
pub fn pad_pose(
    time_s: f64,
    vehicle_ned_m: &Vector3<f64>,
    uav_relative_ned_m: &Vector3<f64>,
) -> PoseStamped {
    PoseStamped {
        header: Header::at(time_s, "map"),
        pose: Pose {
            position: enu(&(vehicle_ned_m - uav_relative_ned_m)),
            orientation: IDENTITY,
        },
    }
}

/// North-east-down to east-north-up.
pub fn enu(ned: &Vector3<f64>) -> Point {
    Point {
        x: ned.y,
        y: ned.x,
        z: -ned.z,
    }
}

/// The vehicle's pose in `map` (ENU), its attitude turned from NED/forward-right-down to
/// ENU/forward-left-up as mavros and PX4's ROS 2 bridge do; `None` before the autopilot reports
/// a local position.
pub fn vehicle_pose(time_s: f64, state: &VehicleState) -> Option<PoseStamped> {
    let position = state.position_ned_m?;
    let attitude = &state.attitude;
    let ned_frd =
        UnitQuaternion::from_euler_angles(attitude.roll_rad, attitude.pitch_rad, attitude.yaw_rad);
    // NED → ENU swaps north and east and turns down into up; FRD → FLU turns about forward.
    let ned_to_enu =
        UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, std::f64::consts::FRAC_PI_2);
    let frd_to_flu = UnitQuaternion::from_euler_angles(std::f64::consts::PI, 0.0, 0.0);
    let q = ned_to_enu * ned_frd * frd_to_flu;
    Some(PoseStamped {
        header: Header::at(time_s, "map"),
        pose: Pose {
            position: enu(&position),
            orientation: Quaternion {
                x: q.i,
                y: q.j,
                z: q.k,
                w: q.w,
            },
        },
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use algorithms::estimation::projection::Attitude;

    fn state(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> VehicleState {
        VehicleState {
            attitude: Attitude {
                roll_rad,
                pitch_rad,
                yaw_rad,
            },
            velocity_ned_m_s: Vector3::zeros(),
            acceleration_ned_m_s2: Vector3::zeros(),
            height_above_pad_m: 5.0,
            position_ned_m: Some(Vector3::new(10.0, 3.0, -20.0)),
            landed: false,
            gimbal_attitude: None,
            offboard: true,
        }
    }

    /// The pose's rotation applied to a vector of the vehicle's FLU frame, in ENU.
    fn rotate(pose: &PoseStamped, v: [f64; 3]) -> Vector3<f64> {
        let q = pose.pose.orientation;
        let q = UnitQuaternion::from_quaternion(nalgebra::Quaternion::new(q.w, q.x, q.y, q.z));
        q * Vector3::new(v[0], v[1], v[2])
    }

    #[test]
    fn the_pose_is_east_north_up_and_the_nose_points_where_the_heading_says() {
        // Facing east (yaw 90° in NED), level: 20 m up, 3 m east, 10 m north.
        let pose = vehicle_pose(1.5, &state(0.0, 0.0, std::f64::consts::FRAC_PI_2)).unwrap();
        assert_eq!(
            pose.pose.position,
            Point {
                x: 3.0,
                y: 10.0,
                z: 20.0
            }
        );
        assert_eq!(pose.header.frame_id, "map");
        assert_eq!(
            pose.header.stamp,
            Time {
                sec: 1,
                nanosec: 500_000_000
            }
        );
        let nose = rotate(&pose, [1.0, 0.0, 0.0]);
        assert!(
            (nose - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12,
            "{nose}"
        );
        let left = rotate(&pose, [0.0, 1.0, 0.0]);
        assert!(
            (left - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12,
            "{left}"
        );
        // Facing north, rolled 30° right (right wing down): the left wing rises.
        let pose = vehicle_pose(0.0, &state(30f64.to_radians(), 0.0, 0.0)).unwrap();
        let nose = rotate(&pose, [1.0, 0.0, 0.0]);
        assert!(
            (nose - Vector3::new(0.0, 1.0, 0.0)).norm() < 1e-12,
            "{nose}"
        );
        let left = rotate(&pose, [0.0, 1.0, 0.0]);
        let expected = Vector3::new(-(30f64.to_radians().cos()), 0.0, 30f64.to_radians().sin());
        assert!((left - expected).norm() < 1e-12, "{left}");
        // Nose up 10°: the nose climbs.
        let pose = vehicle_pose(0.0, &state(0.0, 10f64.to_radians(), 0.0)).unwrap();
        assert!(rotate(&pose, [1.0, 0.0, 0.0]).z > 0.17);
    }

    #[test]
    fn a_battery_reading_keeps_ros_signs_and_marks_what_is_unknown() {
        let telemetry = BatteryTelemetry {
            time_s: 12.25,
            voltage_v: Some(15.2),
            current_a: Some(20.0),
            consumed_mah: Some(1500.0),
            remaining_fraction: None,
        };
        let state = BatteryState::from_telemetry(&telemetry, 5.0);
        assert_eq!(state.voltage, 15.2);
        assert_eq!(state.current, -20.0, "discharging is negative in ROS");
        assert_eq!(state.charge, 3.5);
        assert!(state.percentage.is_nan() && state.temperature.is_nan());
        assert_eq!(state.header.stamp.as_secs(), 12.25);
    }
}
