"""Receives sensor_msgs/Image frames with Cyclone DDS (the reference DDS reader, in its own
process) and prints, as one JSON list, each frame's delay from its header stamp to its arrival
(ms), for FRAMES frames or until SECONDS have passed: the camera latency benchmark's baseline.

    python receive_camera.py TOPIC FRAMES SECONDS
"""

import json
import sys
import time
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from msgs import Image


def main():
    topic, frames, seconds = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
    participant = DomainParticipant(0)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))
    reader = DataReader(participant, Topic(participant, "rt" + topic, Image), qos=sensor)
    delays_ms = []
    end = time.time() + seconds
    while time.time() < end and len(delays_ms) < frames:
        # Woken by the arrival, as qosrt's reader is.
        for sample in reader.take_iter(timeout=duration(milliseconds=100)):
            now = time.time()
            stamp = sample.header.stamp.sec + sample.header.stamp.nanosec * 1e-9
            delays_ms.append((now - stamp) * 1e3)
            break
    print(json.dumps(delays_ms))


main()
