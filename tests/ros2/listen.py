"""An independent ROS 2 subscriber for qosrt's topics: Eclipse Cyclone DDS's Python binding with
the ROS 2 type names and layouts written out from the .msg files (msgs.py), no ROS installed. It prints
each message it receives as one JSON line, and `ready` once its readers exist.

    python listen.py VEHICLE SECONDS
"""

import json
import math
import os
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from msgs import BatteryState, DiagnosticArray, Detection2DArray, PoseStamped, String, TwistStamped


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
    # The most writers each reader ever matched: where nothing arrives, whether discovery failed.
    matched = dict.fromkeys(readers, 0)
    next_count = time.time()
    while time.time() < end:
        if time.time() >= next_count:
            next_count += 0.5
            for name, reader in readers.items():
                matched[name] = max(matched[name], len(reader.get_matched_publications()))
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
    print(f"listen.py: the most writers matched per topic: {matched}", file=sys.stderr, flush=True)


try:
    main()
except BrokenPipeError:
    # The test read what it needed and closed the pipe: leave quietly (Python's docs' recipe,
    # so that the interpreter's own flush at exit does not fail again).
    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    sys.exit(0)
