"""Publishes mono8 camera frames on a ROS 2 topic as a camera driver would (sensor_msgs/Image,
the header stamped just before publishing, sensor-data QoS), for the camera latency benchmark.

Python's serializer takes about 10 ms for a 640×480 frame, which a C++ driver does not: the
frame is serialized once, and each one is that buffer with its stamp rewritten in place (after
the 4-byte CDR header, `sec` and `nanosec` come first), handed to Cyclone DDS's write as bytes.
So the stamp is taken just before the bytes go out, as a driver's would be.

    python publish_camera.py TOPIC SECONDS WIDTH HEIGHT FPS
"""

import struct
import sys
import time

import cyclonedds.pub as cyclone_pub
from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic

from msgs import Header, Image, Time


def main():
    topic, seconds = sys.argv[1], float(sys.argv[2])
    width, height, fps = int(sys.argv[3]), int(sys.argv[4]), float(sys.argv[5])
    participant = DomainParticipant(0)
    sensor = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))
    writer = DataWriter(participant, Topic(participant, "rt" + topic, Image), qos=sensor)
    pixels = bytes((i * 7) % 256 for i in range(width * height))
    frame = Image(Header(Time(0, 0), "camera"), height, width, "mono8", 0, width, pixels)
    serialized = frame.serialize()
    buffer = bytearray(serialized.ljust((len(serialized) + 3) & ~3, b"\0"))
    little_endian = buffer[1] == 1
    layout = "<iI" if little_endian else ">iI"
    end = time.time() + seconds
    next_frame = time.time()
    while time.time() < end:
        now = time.time()
        struct.pack_into(layout, buffer, 4, int(now), int((now - int(now)) * 1e9))
        cyclone_pub.ddspy_write(writer._ref, bytes(buffer))
        next_frame += 1.0 / fps
        time.sleep(max(0.0, next_frame - time.time()))


main()
