"""Reads a canodom MCAP file with independent readers from PyPI and checks it
against the CSV of the same replay (issue #25's must-shows).

    python check_mcap.py FILE.mcap FILE.csv STEPS FRAMES

- the MCAP library (`mcap`) reads every record, with the file's index and
  without it (a streaming read, as after a crash), and every channel holds
  exactly STEPS messages; the raw-frame messages hold FRAMES frames in all;
- `mcap-ros2-support` decodes every message with the file's own schemas
  (every channel is CDR: the Foxglove ones as `foxglove_msgs/msg/...`);
- `rosbags` deserialises every message: `Odometry` and `TFMessage` with
  its own built-in definitions (ROS 2 Humble), independent of the file's
  schemas; the others with the types the file's schemas define; and its own
  reader (`rosbags.rosbag2.Reader`, as a ROS user opens a bag) reads the
  whole file;
- the last Odometry equals the CSV's last row (time, x, y, heading, speed);
- every covariance is symmetric and positive definite.

Exits non-zero with the reason on the first failure; prints a summary line.
"""

import csv
import math
import sys
from pathlib import Path

import numpy as np
from mcap.reader import NonSeekingReader, make_reader
from mcap_ros2.decoder import DecoderFactory as Ros2Decoders
from rosbags.rosbag2 import Reader as RosbagsReader
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

TOPICS = [
    "/canodom/pose",
    "/canodom/rear_odometry",
    "/canodom/transform",
    "/canodom/quality",
    "/canodom/gate",
    "/canodom/calibration",
    "/canodom/can",
    "/odom",
    "/tf",
]


def fail(why):
    print(f"check_mcap: FAIL: {why}", file=sys.stderr)
    sys.exit(1)


def check(cond, why):
    if not cond:
        fail(why)


def covariance_ok(values, what):
    m = np.array(values, dtype=float).reshape(6, 6)
    check(np.array_equal(m, m.T), f"{what}: covariance not symmetric")
    eig = np.linalg.eigvalsh(m)
    check(eig.min() > 0.0, f"{what}: covariance not positive definite (eigenvalue {eig.min()})")


def register(typestore, name, text):
    """Registers the types a ros2msg schema defines that the store lacks."""
    sep = "=" * 80
    parts = [p.strip("\n") for p in text.split(sep)]
    defs = {name: parts[0]}
    for part in parts[1:]:
        head, _, body = part.partition("\n")
        pkg, _, ty = head.removeprefix("MSG: ").partition("/")
        defs[f"{pkg}/msg/{ty.split('/')[-1]}"] = body
    for ty, body in defs.items():
        if ty not in typestore.fielddefs:
            typestore.register(get_types_from_msg(body, ty))


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def wrap(a):
    return math.atan2(math.sin(a), math.cos(a))


def main():
    path, csv_path, steps, frames = sys.argv[1], sys.argv[2], int(sys.argv[3]), int(sys.argv[4])
    typestore = get_typestore(Stores.ROS2_HUMBLE)
    counts = dict.fromkeys(TOPICS, 0)
    can_frames = 0
    last_odom = None
    last_pose = None
    last_quality = None
    with open(path, "rb") as f:
        reader = make_reader(f)
        ros2 = Ros2Decoders()
        decoders = {}
        registered = set()
        summary = reader.get_summary()
        check(summary is not None, "no summary section: the file was not finished")
        indexed = {summary.channels[c].topic: n for c, n in summary.statistics.channel_message_counts.items()}
        check(set(indexed) == set(TOPICS), f"channels {sorted(indexed)}, expected {sorted(TOPICS)}")
        for schema, channel, message in reader.iter_messages():
            topic = channel.topic
            check(channel.message_encoding == "cdr" and schema.encoding == "ros2msg",
                  f"{topic}: {channel.message_encoding}/{schema.encoding}, not cdr/ros2msg "
                  "(the ros2 profile; ros2 bag play refuses mixed encodings)")
            if channel.id not in decoders:
                decoders[channel.id] = ros2.decoder_for(channel.message_encoding, schema)
            decoded = decoders[channel.id](message.data)
            counts[topic] += 1
            # rosbags: ROS 2 Humble's own definitions, the file's for the rest.
            if schema.id not in registered:
                register(typestore, schema.name, schema.data.decode())
                registered.add(schema.id)
            ros = typestore.deserialize_cdr(message.data, schema.name)
            if topic == "/canodom/can":
                check(len(ros.frames) == len(decoded.frames), "CanFrames: the readers disagree")
                can_frames += len(ros.frames)
            if topic == "/odom":
                covariance_ok(ros.pose.covariance, "Odometry pose (rosbags)")
                covariance_ok(ros.twist.covariance, "Odometry twist (rosbags)")
                check(decoded.child_frame_id == "base_link" and decoded.header.frame_id == "odom",
                      "Odometry frames are not odom -> base_link")
                check(list(decoded.pose.covariance) == list(ros.pose.covariance),
                      "mcap-ros2-support and rosbags disagree")
                last_odom = (message.log_time, decoded, ros)
            elif topic == "/tf":
                check(len(ros.transforms) == 1 and ros.transforms[0].child_frame_id == "base_link",
                      "TFMessage is not one odom -> base_link transform")
            elif topic == "/canodom/quality":
                check(ros.quality == decoded.quality and (ros.quality & 1) == ros.pose_valid,
                      "Quality: the readers disagree, or POSE_VALID is not bit 0")
                last_quality = ros
            if topic == "/canodom/pose":
                last_pose = decoded
    for topic, n in counts.items():
        check(n == steps, f"{topic}: {n} messages, the replay took {steps} steps")
        check(indexed[topic] == n, f"{topic}: the index says {indexed[topic]}, the file holds {n}")
    check(can_frames == frames, f"/canodom/can holds {can_frames} frames, the replay read {frames}")

    # rosbags' own reader, as a ROS user opens a bag: every message, each
    # deserialised with the store the first pass filled.
    with RosbagsReader(Path(path)) as bag:
        by_topic = {c.topic: c.msgcount for c in bag.connections}
        check(by_topic == dict.fromkeys(TOPICS, steps), f"rosbags Reader: {by_topic}")
        bag_read = sum(1 for c, _, raw in bag.messages() if typestore.deserialize_cdr(raw, c.msgtype))
    check(bag_read == steps * len(TOPICS), f"rosbags Reader read {bag_read} messages")

    # The same records without the index, read as a stream from the start.
    with open(path, "rb") as f:
        streamed = sum(1 for _ in NonSeekingReader(f).iter_messages())
    check(streamed == steps * len(TOPICS), f"streamed read found {streamed} messages")

    with open(csv_path, newline="") as f:
        rows = list(csv.DictReader(f))
    check(len(rows) == steps, f"the CSV has {len(rows)} rows, expected {steps}")
    last = rows[-1]
    t_ns, odom, ros = last_odom
    t_csv = round(float(last["t_unix_s"]) * 1e9)
    check(abs(t_ns - t_csv) <= 1000, f"last Odometry at {t_ns} ns, CSV's last row at {t_csv} ns")
    stamp = ros.header.stamp.sec * 1_000_000_000 + ros.header.stamp.nanosec
    check(stamp == t_ns, "Odometry stamp differs from its log time")
    p = odom.pose.pose
    for name, got, want in [
        ("x", p.position.x, float(last["x_m"])),
        ("y", p.position.y, float(last["y_m"])),
        ("heading", wrap(yaw_of(p.orientation) - float(last["heading_rad"])), 0.0),
        ("speed", odom.twist.twist.linear.x, float(last["speed_mps"])),
        # As variances: canodom adds a floor of 1e-8 to the estimated ones.
        ("pos_var", max(np.linalg.eigvalsh(np.array(odom.pose.covariance).reshape(6, 6)[:2, :2])),
         float(last["pos_std_m"]) ** 2),
    ]:
        check(abs(got - want) <= 1e-9 * max(1.0, abs(want)) + 2e-8 * (name == "pos_var"),
              f"last Odometry {name} {got}, CSV {want}")
    check(last_quality.quality == int(last["quality"]), "last Quality differs from the CSV")
    check(last_pose is not None and abs(last_pose.pose.position.x - float(last["x_m"])) < 1e-9,
          "last foxglove.PoseInFrame differs from the CSV")
    print(f"check_mcap: ok: {len(TOPICS)} channels x {steps} messages, {can_frames} CAN frames, "
          f"last Odometry = CSV last row, covariances symmetric positive definite, "
          f"rosbags deserialised {len(TOPICS) * steps} messages, twice (its reader too)")


if __name__ == "__main__":
    main()
