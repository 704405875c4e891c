"""Publishes camera frames on a ROS 2 topic as a camera driver would: sensor_msgs/Image with the
header stamped at capture (here: just before publishing), 64×48, at 50 Hz, from Eclipse Cyclone
DDS's Python binding. Frame n's first two pixels carry n (low byte, high byte); every tenth
frame is in an encoding qosrt does not read (yuv422), every tenth from the fifth has the wrong
size, every tenth from the third is rgb8.

    python publish_frames.py TOPIC SECONDS
"""

import sys
import time
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from msgs import Header, Image, Time


def frame(n):
    width, height = (80, 48) if n % 10 == 5 else (64, 48)
    grey = [(x * 3 + y * 5) % 256 for y in range(height) for x in range(width)]
    grey[0], grey[1] = n % 256, n // 256
    if n % 10 == 3:
        # Grey as colour: equal channels keep the same luma.
        return "rgb8", width, height, 3 * width, [c for g in grey for c in (g, g, g)]
    if n % 10 == 0:
        return "yuv422", width, height, 2 * width, [128] * (2 * width * height)
    return "mono8", width, height, width, grey


def main():
    topic, seconds = sys.argv[1], float(sys.argv[2])
    participant = DomainParticipant(0)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))
    writer = DataWriter(participant, Topic(participant, "rt" + topic, Image), qos=sensor)
    end = time.time() + seconds
    n = 0
    while time.time() < end:
        encoding, width, height, step, data = frame(n)
        now = time.time()
        stamp = Time(sec=int(now), nanosec=int((now - int(now)) * 1e9))
        writer.write(Image(Header(stamp, "camera"), height, width, encoding, 0, step, data))
        n += 1
        time.sleep(0.02)


main()
