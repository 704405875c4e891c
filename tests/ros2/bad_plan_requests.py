"""Sends a vehicle's plan_request topic what is not a plan request, as a broken or foreign
client would, and prints each answer the vehicle gives (one JSON per line):

- malformed CDR: a std_msgs/String whose length field claims 4 GB (a struct of one uint32
  under String's type name, so the bytes on the wire are exactly that);
- a well-formed String whose text is not JSON;
- a String with JSON that is not a request (an unknown field).

    python bad_plan_requests.py VEHICLE SECONDS
"""

import json
import sys
import time
from dataclasses import dataclass

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration

from msgs import String


@dataclass
class NotAString(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    length: uint32


def main():
    vehicle, seconds = sys.argv[1], float(sys.argv[2])
    participant = DomainParticipant(0)
    qos = Qos(Policy.Reliability.Reliable(duration(milliseconds=100)), Policy.Durability.Volatile, Policy.History.KeepLast(10))
    name = f"rt/qosrt/{vehicle}/plan_request"
    # A participant of its own: one participant holds one type per topic name.
    foreign = DomainParticipant(0)
    bad_writer = DataWriter(foreign, Topic(foreign, name, NotAString), qos=qos)
    writer = DataWriter(participant, Topic(participant, name, String), qos=qos)
    answers = DataReader(
        participant, Topic(participant, f"rt/qosrt/{vehicle}/plan_answer", String), qos=qos
    )
    end = time.time() + seconds
    seen = set()
    while time.time() < end and len(seen) < 3:
        # Until every kind has been answered: the first sends may precede discovery.
        bad_writer.write(NotAString(0xFFFFFFF0))
        writer.write(String("reserve please"))
        writer.write(String(json.dumps({"id": 9, "reserve": 0.3})))
        deadline = time.time() + 1.0
        while time.time() < deadline:
            for sample in answers.take(10):
                answer = json.loads(sample.data)
                refusal = answer.get("refusal") or ""
                kind = "cdr" if "CDR" in refusal else "json" if "expected value" in refusal else "field"
                if kind not in seen:
                    seen.add(kind)
                    print(json.dumps(answer), flush=True)
            time.sleep(0.02)


main()
