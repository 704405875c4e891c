"""An independent ROS 2 subscriber for qosrt's topics: Eclipse Cyclone DDS's Python binding with
the ROS 2 type names and layouts written out from the .msg files, no ROS installed. It prints
each message it receives as one JSON line, and `ready` once its readers exist.

    python listen.py VEHICLE SECONDS
"""

import json
import math
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int32, sequence, uint8, uint32
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64
    y: float64
    z: float64


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64
    y: float64
    z: float64
    w: float64


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point
    orientation: Quaternion


@dataclass
class PoseStamped(IdlStruct, typename="geometry_msgs::msg::dds_::PoseStamped_"):
    header: Header
    pose: Pose


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TwistStamped_"):
    header: Header
    twist: Twist


@dataclass
class BatteryState(IdlStruct, typename="sensor_msgs::msg::dds_::BatteryState_"):
    header: Header
    voltage: float32
    temperature: float32
    current: float32
    charge: float32
    capacity: float32
    design_capacity: float32
    percentage: float32
    power_supply_status: uint8
    power_supply_health: uint8
    power_supply_technology: uint8
    present: bool
    cell_voltage: sequence[float32]
    cell_temperature: sequence[float32]
    location: str
    serial_number: str


@dataclass
class KeyValue(IdlStruct, typename="diagnostic_msgs::msg::dds_::KeyValue_"):
    key: str
    value: str


@dataclass
class DiagnosticStatus(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticStatus_"):
    level: uint8
    name: str
    message: str
    hardware_id: str
    values: sequence[KeyValue]


@dataclass
class DiagnosticArray(IdlStruct, typename="diagnostic_msgs::msg::dds_::DiagnosticArray_"):
    header: Header
    status: sequence[DiagnosticStatus]


@dataclass
class Point2D(IdlStruct, typename="vision_msgs::msg::dds_::Point2D_"):
    x: float64
    y: float64


@dataclass
class Pose2D(IdlStruct, typename="vision_msgs::msg::dds_::Pose2D_"):
    position: Point2D
    theta: float64


@dataclass
class BoundingBox2D(IdlStruct, typename="vision_msgs::msg::dds_::BoundingBox2D_"):
    center: Pose2D
    size_x: float64
    size_y: float64


@dataclass
class ObjectHypothesis(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesis_"):
    class_id: str
    score: float64


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class ObjectHypothesisWithPose(IdlStruct, typename="vision_msgs::msg::dds_::ObjectHypothesisWithPose_"):
    hypothesis: ObjectHypothesis
    pose: PoseWithCovariance


@dataclass
class Detection2D(IdlStruct, typename="vision_msgs::msg::dds_::Detection2D_"):
    header: Header
    results: sequence[ObjectHypothesisWithPose]
    bbox: BoundingBox2D
    id: str


@dataclass
class Detection2DArray(IdlStruct, typename="vision_msgs::msg::dds_::Detection2DArray_"):
    header: Header
    detections: sequence[Detection2D]


def stamp(header):
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def number(value):
    return None if math.isnan(value) else value


def main():
    vehicle, seconds = sys.argv[1], float(sys.argv[2])
    participant = DomainParticipant(0)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(100))
    state = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(100),
    )
    topics = {
        "pose": (PoseStamped, sensor),
        "battery": (BatteryState, sensor),
        "velocity_setpoint": (TwistStamped, sensor),
        "phase": (String, state),
        "governor": (String, state),
        "diagnostics": (DiagnosticArray, state),
        "pad_pose": (PoseStamped, sensor),
        "hazards": (Detection2DArray, sensor),
        "plan": (String, state),
    }
    readers = {
        name: DataReader(participant, Topic(participant, f"rt/qosrt/{vehicle}/{name}", kind), qos=qos)
        for name, (kind, qos) in topics.items()
    }
    print("ready", flush=True)
    end = time.time() + seconds
    while time.time() < end:
        for name, reader in readers.items():
            for sample in reader.take(200):
                if not hasattr(sample, "header") and not hasattr(sample, "data"):
                    continue  # the writer went away: an instance state change, not a message
                out = {"topic": name}
                if name in ("pose", "pad_pose"):
                    p, q = sample.pose.position, sample.pose.orientation
                    out.update(t=stamp(sample.header), frame=sample.header.frame_id,
                               position=[p.x, p.y, p.z], orientation=[q.x, q.y, q.z, q.w])
                elif name == "battery":
                    out.update(t=stamp(sample.header), voltage=number(sample.voltage),
                               current=number(sample.current), percentage=number(sample.percentage),
                               design_capacity=sample.design_capacity, present=sample.present)
                elif name == "velocity_setpoint":
                    v = sample.twist.linear
                    out.update(t=stamp(sample.header), frame=sample.header.frame_id, linear=[v.x, v.y, v.z])
                elif name == "hazards":
                    out.update(t=stamp(sample.header), detections=[
                        {"class": d.results[0].hypothesis.class_id, "score": d.results[0].hypothesis.score,
                         "box": [d.bbox.center.position.x, d.bbox.center.position.y, d.bbox.size_x, d.bbox.size_y],
                         "covariance0": d.results[0].pose.covariance[0]}
                        for d in sample.detections])
                elif name == "diagnostics":
                    out.update(t=stamp(sample.header), status=[
                        {"name": s.name, "level": s.level, "values": {kv.key: kv.value for kv in s.values}}
                        for s in sample.status])
                else:
                    out.update(data=sample.data)
                print(json.dumps(out), flush=True)
        time.sleep(0.01)


main()
