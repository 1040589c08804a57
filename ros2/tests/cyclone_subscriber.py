#!/usr/bin/env python3
"""Interoperability of `canodom replay --ros2` with Eclipse Cyclone DDS (issue #43).

A Cyclone DDS participant (PyPI `cyclonedds`, the DDS ROS 2 ships by default)
with the ROS 2 message definitions as IDL subscribes to `/odom` (a reliable and
a best-effort reader), `/tf` and `/diagnostics` on a domain of its own, over
loopback only: unicast discovery with 127.0.0.1 as the one peer, multicast
off, so nothing is sent but to 127.0.0.1. It starts `canodom replay --ros2` of
a drive, then checks what arrived against `canodom replay`'s CSV of the same
drive: every step, at the log's rate, with the CSV's pose (x, y, heading).

Run as CI runs it (ros2/tests/cyclone.sh makes the venv):
    python ros2/tests/cyclone_subscriber.py --canodom target/debug/canodom \
        --config data/comma2k19-rav4/config.toml --log data/comma2k19-rav4/drive.log
Exit 0 when every check passes; the measurements go to stdout.
"""

import argparse
import csv
import math
import os
import re
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path


def cyclone_uri() -> str:
    """Loopback only, no multicast, discovery by unicast to 127.0.0.1's well-known ports."""
    return (
        "<CycloneDDS><Domain Id='any'><General><Interfaces>"
        "<NetworkInterface address='127.0.0.1'/></Interfaces>"
        "<AllowMulticast>false</AllowMulticast></General>"
        "<Discovery><Peers><Peer address='127.0.0.1'/></Peers>"
        "<ParticipantIndex>auto</ParticipantIndex>"
        "<MaxAutoParticipantIndex>20</MaxAutoParticipantIndex></Discovery>"
        "</Domain></CycloneDDS>"
    )


# The environment must hold the configuration before the library starts a domain.
os.environ["CYCLONEDDS_URI"] = cyclone_uri()

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication  # noqa: E402
from cyclonedds.core import Policy, Qos  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl import IdlStruct  # noqa: E402
from cyclonedds.idl.types import (  # noqa: E402
    array,
    float64,
    int8,
    int32,
    sequence,
    uint8,
    uint16,
    uint32,
)
from cyclonedds.pub import DataWriter  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from cyclonedds.util import duration  # noqa: E402


# ROS 2 message definitions as IDL (the names rosidl gives them on DDS).
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


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
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose
    covariance: array[float64, 36]


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3
    angular: Vector3


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist
    covariance: array[float64, 36]


@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header
    child_frame_id: str
    pose: PoseWithCovariance
    twist: TwistWithCovariance


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3
    rotation: Quaternion


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header
    child_frame_id: str
    transform: Transform


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: sequence[TransformStamped]


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
class NavSatStatus(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatStatus_"):
    status: int8
    service: uint16


@dataclass
class NavSatFix(IdlStruct, typename="sensor_msgs::msg::dds_::NavSatFix_"):
    header: Header
    status: NavSatStatus
    latitude: float64
    longitude: float64
    altitude: float64
    position_covariance: array[float64, 9]
    position_covariance_type: uint8


# ROS 2's graph topic (rmw_dds_common): Gid is char[16] since Iron (Jazzy), as canodom's default.
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: array[uint8, 16]


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str
    node_name: str
    reader_gid_seq: sequence[Gid]
    writer_gid_seq: sequence[Gid]


@dataclass
class ParticipantEntitiesInfo(
    IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
):
    gid: Gid
    node_entities_info_seq: sequence[NodeEntitiesInfo]


def ros2_qos(reliable: bool, depth: int) -> Qos:
    """ROS 2's default profile (reliable) or its sensor-data profile (best effort)."""
    return Qos(
        Policy.Reliability.Reliable(duration(seconds=1))
        if reliable
        else Policy.Reliability.BestEffort,
        Policy.Durability.Volatile,
        Policy.History.KeepLast(depth),
    )


def stamp_us(header: Header) -> int:
    return header.stamp.sec * 1_000_000 + header.stamp.nanosec // 1000


def wrap(a: float) -> float:
    return math.atan2(math.sin(a), math.cos(a))


def config_with(config: Path, section: str, folder: Path) -> Path:
    """A copy of `config` with `section` appended, its DBC path made absolute."""
    text = config.read_text()

    def absolute(m: re.Match) -> str:
        return f'dbc = "{(config.parent / m.group(1)).resolve()}"'

    text = re.sub(r'^dbc\s*=\s*"([^"]+)"', absolute, text, flags=re.M)
    out = folder / "config.toml"
    out.write_text(text + "\n" + section + "\n")
    return out


def reference(args, folder: Path) -> dict:
    """`canodom replay`'s CSV rows by their time on the log's clock (µs)."""
    out = folder / "reference.csv"
    subprocess.run(
        [args.canodom, "replay", "--config", args.config, args.log, "--out", out],
        check=True,
        stderr=subprocess.DEVNULL,
    )
    rows = {}
    with out.open() as f:
        for row in csv.DictReader(f):
            t_us = round(float(row["t_unix_s"]) * 1e6)
            rows[t_us] = (float(row["x_m"]), float(row["y_m"]), float(row["heading_rad"]))
    return rows


def run(args, qos_name: str, speed: float, rows: dict, folder: Path) -> list:
    """One replay published with `qos_name`, received by every reader; the failures."""
    failures = []
    dp = DomainParticipant(args.domain)
    odom_topic = Topic(dp, "rt/odom", Odometry)
    readers = {
        "reliable": DataReader(dp, odom_topic, qos=ros2_qos(True, 100)),
        "best_effort": DataReader(dp, odom_topic, qos=ros2_qos(False, 100)),
    }
    tf_reader = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=ros2_qos(True, 100))
    diag_reader = DataReader(
        dp, Topic(dp, "rt/diagnostics", DiagnosticArray), qos=ros2_qos(True, 10)
    )
    # The section's domain and discovery: the environment's are checked by the other run.
    config = config_with(
        Path(args.config),
        f'[ros2]\nqos = "{qos_name}"\ndomain_id = {args.domain}\ndiscovery = "localhost"',
        folder,
    )
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)
    # The best-effort reader matches either writer; wait for both readers where both can match.
    want = 2 if qos_name == "default" else 1
    cmd = [
        args.canodom, "replay", "--config", str(config), args.log, "--ros2",
        "--ros2-wait", str(want), "--ros2-speed", str(speed),
    ]
    started = time.monotonic()
    # Its log to a file: a pipe nobody reads while it runs would fill and stall it.
    log = open(folder / f"replay-{qos_name}.log", "w+")
    proc = subprocess.Popen(cmd, env=env, stderr=log, text=True)
    received = {name: [] for name in readers}
    tfs, diags = [], []
    while True:
        done = proc.poll() is not None
        for name, reader in readers.items():
            for s in reader.take(N=256):
                received[name].append((time.monotonic(), s))
        tfs.extend(tf_reader.take(N=256))
        diags.extend(diag_reader.take(N=64))
        if done:
            # What the last writes put on the wire is in by now (the node lingers for acks).
            time.sleep(0.5)
            for name, reader in readers.items():
                for s in reader.take(N=256):
                    received[name].append((time.monotonic(), s))
            tfs.extend(tf_reader.take(N=256))
            diags.extend(diag_reader.take(N=64))
            break
        time.sleep(0.005)
    log.seek(0)
    stderr = log.read()
    log.close()
    # Samples only: Cyclone also hands over the writer's going away (InvalidSample).
    received = {n: [(t, s) for t, s in v if isinstance(s, Odometry)] for n, v in received.items()}
    tfs = [m for m in tfs if isinstance(m, TFMessage)]
    diags = [m for m in diags if isinstance(m, DiagnosticArray)]
    if proc.returncode != 0:
        failures.append(f"canodom replay --ros2 exited {proc.returncode}: {stderr}")
    steps = len(rows)
    log_s = (max(rows) - min(rows)) / 1e6 if rows else 0.0
    print(f"\n== /odom writer QoS {qos_name}, pace x{speed}: {steps} steps over {log_s:.3f} s of log "
          f"(the log's rate x{speed}: {steps / log_s * speed if log_s else 0:.2f} Hz), run {time.monotonic() - started:.1f} s")
    for line in stderr.splitlines():
        if "replay:" in line:
            print("   canodom:", line.strip())
    for name, samples in received.items():
        should = qos_name == "default" or name == "best_effort"
        n = len(samples)
        if n == 0:
            print(f"  {name:11} reader: 0 samples" + ("" if should else " (as DDS wants: a reliable reader does not match a best-effort writer)"))
            if should:
                failures.append(f"{qos_name}: the {name} reader received nothing")
            continue
        span = samples[-1][0] - samples[0][0]
        rate = (n - 1) / span if span > 0 else float("nan")
        max_pos, max_head, missing = 0.0, 0.0, 0
        frames = set()
        got = {stamp_us(s.header) for _, s in samples}
        lost = sorted(set(rows) - got)
        if lost:
            t0 = min(rows)
            print(f"  {name:11} reader: steps not received (s after the first): "
                  f"{[round((t - t0) / 1e6, 3) for t in lost[:10]]}")
        for _, s in samples:
            key = stamp_us(s.header)
            frames.add((s.header.frame_id, s.child_frame_id))
            if key not in rows:
                missing += 1
                continue
            x, y, h = rows[key]
            p = s.pose.pose.position
            q = s.pose.pose.orientation
            max_pos = max(max_pos, abs(p.x - x), abs(p.y - y))
            max_head = max(max_head, abs(wrap(2 * math.atan2(q.z, q.w) - h)))
        print(f"  {name:11} reader: {n} of {steps} samples, {rate:.2f} Hz received, "
              f"max |dx|,|dy| {max_pos:.3g} m, max heading diff {max_head:.3g} rad, "
              f"stamps not in the CSV {missing}, frames {sorted(frames)}")
        if not should:
            failures.append(f"{qos_name}: the {name} reader received {n} samples, expected none")
        if missing:
            failures.append(f"{qos_name}/{name}: {missing} stamps are no CSV step's")
        if max_pos > 1e-9 or max_head > 1e-9:
            failures.append(f"{qos_name}/{name}: poses differ from the CSV by {max_pos}, {max_head}")
        # Reliable over loopback: every step. Best effort may lose some (UDP), not most.
        least = steps if (name == "reliable") else int(0.95 * steps)
        if n < least:
            failures.append(f"{qos_name}/{name}: {n} of {steps} steps received (want >= {least})")
        expected_rate = steps / log_s * speed if log_s else 0
        if name == "reliable" and expected_rate and abs(rate / expected_rate - 1) > 0.05:
            failures.append(f"{qos_name}/{name}: rate {rate:.2f} Hz, the log's is {expected_rate:.2f} Hz")
    transforms = [t for m in tfs for t in m.transforms]
    print(f"  /tf: {len(tfs)} messages; frames "
          f"{sorted({(t.header.frame_id, t.child_frame_id) for t in transforms})}")
    if transforms:
        t = transforms[-1]
        print(f"  last /tf: {t.header.frame_id} -> {t.child_frame_id} at "
              f"{t.header.stamp.sec}.{t.header.stamp.nanosec:09d}: translation "
              f"({t.transform.translation.x:.4f}, {t.transform.translation.y:.4f}), "
              f"rotation z,w ({t.transform.rotation.z:.6f}, {t.transform.rotation.w:.6f})")
    if len(tfs) < steps:
        failures.append(f"{qos_name}: /tf {len(tfs)} of {steps} messages")
    print(f"  /diagnostics: {len(diags)} messages (1 Hz over {log_s / speed:.1f} s)")
    if diags:
        d = diags[len(diags) // 2]
        print(f"  one /diagnostics at {d.header.stamp.sec}.{d.header.stamp.nanosec:09d}:")
        for st in d.status:
            vals = ", ".join(f"{kv.key}={kv.value}" for kv in st.values)
            print(f"    [{st.level}] {st.name}: {st.message} ({st.hardware_id}) {vals}")
    if len(diags) < int(log_s / speed) - 2:
        failures.append(f"{qos_name}: {len(diags)} /diagnostics over {log_s / speed:.1f} s")
    del readers, tf_reader, diag_reader, dp
    return failures


def ros_graph(args, folder: Path) -> list:
    """What `ros2 node list` / `ros2 topic info -v` read: canodom's sample on
    `ros_discovery_info` names the node and its writers by GUID; the GUIDs must
    be those DDS discovery reports for the `rt/...` writers of the same participant.
    A second graph reader made once the node runs checks the sample is kept for
    late joiners (transient-local), as tools start after the node."""
    failures = []
    dp = DomainParticipant(args.domain)
    graph_qos = Qos(
        Policy.Reliability.Reliable(duration(seconds=1)),
        Policy.Durability.TransientLocal,
        Policy.History.KeepLast(1),
    )
    graph_topic = Topic(dp, "ros_discovery_info", ParticipantEntitiesInfo)
    early = DataReader(dp, graph_topic, qos=graph_qos)
    odom = DataReader(dp, Topic(dp, "rt/car1/odom", Odometry), qos=ros2_qos(True, 100))
    publications = BuiltinDataReader(dp, BuiltinTopicDcpsPublication)
    config = config_with(
        Path(args.config),
        f'[ros2]\ndomain_id = {args.domain}\ndiscovery = "localhost"\nnode_name = "canodom_graph"\n'
        'namespace = "/car1"',
        folder,
    )
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)
    log = open(folder / "replay-graph.log", "w+")
    proc = subprocess.Popen(
        [args.canodom, "replay", "--config", str(config), args.log, "--ros2",
         "--ros2-wait", "1", "--ros2-speed", "20"],
        env=env, stderr=log, text=True,
    )
    infos, endpoints, late, late_infos, odoms = [], [], None, [], 0
    while True:
        done = proc.poll() is not None
        infos.extend(s for s in early.take(N=16) if isinstance(s, ParticipantEntitiesInfo))
        endpoints.extend(publications.take(N=64))
        got = [s for s in odom.take(N=256) if isinstance(s, Odometry)]
        odoms += len(got)
        if late is None and odoms > 0:
            # The node has been up a while: a tool started now.
            late = DataReader(dp, graph_topic, qos=graph_qos)
        if late is not None:
            late_infos.extend(s for s in late.take(N=16) if isinstance(s, ParticipantEntitiesInfo))
        if done:
            break
        time.sleep(0.01)
    log.close()
    print("\n== ROS 2 graph (ros_discovery_info, what `ros2 node list` reads)")
    ours = [e for e in endpoints if e.topic_name == "rt/car1/odom"]
    if not ours:
        failures.append("graph: DDS discovery reported no rt/car1/odom writer")
        return failures
    odom_ep = ours[0]
    participant = odom_ep.participant_key.bytes
    print(f"  DDS discovery: writer of {odom_ep.topic_name} ({odom_ep.type_name}) GUID {odom_ep.key.bytes.hex()}, "
          f"participant {participant.hex()}")
    mine = [i for i in infos if bytes(i.gid.data) == participant]
    if not mine:
        failures.append(f"graph: no ros_discovery_info sample with the participant's GID "
                        f"(received {len(infos)} from {[bytes(i.gid.data).hex() for i in infos]})")
        return failures
    info = mine[-1]
    nodes = [(n.node_namespace, n.node_name) for n in info.node_entities_info_seq]
    print(f"  ros_discovery_info: participant GID {bytes(info.gid.data).hex()}, nodes {nodes}")
    if nodes != [("/car1", "canodom_graph")]:
        failures.append(f"graph: nodes {nodes}, expected [('/car1', 'canodom_graph')]")
    node = info.node_entities_info_seq[0] if info.node_entities_info_seq else None
    writer_gids = {bytes(g.data) for g in node.writer_gid_seq} if node else set()
    by_topic = {e.topic_name: e.key.bytes for e in endpoints if e.participant_key.bytes == participant}
    for topic in ("rt/car1/odom", "rt/tf", "rt/diagnostics"):
        guid = by_topic.get(topic)
        ok = guid is not None and guid in writer_gids
        print(f"  writer {topic}: DDS GUID {guid.hex() if guid else None}, in the node's writer GIDs: {ok}")
        if not ok:
            failures.append(f"graph: the {topic} writer's GUID is not among the node's writer GIDs")
    late_mine = [i for i in late_infos if bytes(i.gid.data) == participant]
    print(f"  a graph reader made after the node started: {len(late_mine)} sample(s) (transient-local)")
    if not late_mine:
        failures.append("graph: a late-joining ros_discovery_info reader got nothing")
    if proc.returncode != 0:
        failures.append(f"graph: canodom replay --ros2 exited {proc.returncode}")
    del early, late, odom, publications, dp
    return failures


def fixes_from_ros2(args, folder: Path) -> list:
    """Cyclone publishes the RAV4 truth's first 30 s as NavSatFix at 1 Hz;
    `canodom ros2-fixes` writes them as a CSV; `calibrate --fixes` gives the
    same estimate from it as from the same fixes written straight to a file."""
    failures = []
    d = Path(args.config).parent
    truth = list(csv.DictReader((d / "truth.csv").open()))
    t0 = float(truth[0]["t_unix_s"])
    picked = [r for k, r in enumerate(truth) if k % 20 == 0 and float(r["t_unix_s"]) - t0 <= 30]
    # Local metres to WGS-84 near an arbitrary origin (east x, north y): the
    # two paths share the latitudes and longitudes, whatever their accuracy.
    lat0, lon0, r = 37.4, -122.1, 6_378_137.0
    fixes = []
    for row in picked:
        # On NMEA's grid (centiseconds; minutes to 7 decimals), so that the
        # NMEA file below holds the very fixes ROS 2 carries.
        t = round(float(row["t_unix_s"]), 2)
        sec = int(t)
        nanosec = int(round((t - sec) * 100)) * 10_000_000
        lat = nmea_grid(lat0 + math.degrees(float(row["y_m"]) / r))
        lon = nmea_grid(lon0 + math.degrees(float(row["x_m"]) / (r * math.cos(math.radians(lat0)))))
        fixes.append((sec, nanosec, lat, lon, 12.5))
    direct = folder / "fixes-direct.csv"
    with direct.open("w") as f:
        # horiz_std_m: the published covariance's east/north 0.25 m² is σ 0.5 m.
        f.write("t_unix_s,lat_deg,lon_deg,alt_m,horiz_std_m\n")
        for sec, ns, lat, lon, alt in fixes:
            # The stamp as canodom turns it into seconds (sec + nanosec·1e-9, one double).
            # Degrees as the shortest text that reads back to the same double.
            f.write(f"{float(sec) + ns * 1e-9:.9f},{lat!r},{lon!r},{alt:.3f},0.500\n")
    nmea = folder / "fixes.nmea"
    nmea.write_text("".join(nmea_epoch(sec, ns, lat, lon, alt, 0.5) for sec, ns, lat, lon, alt in fixes))
    via_ros2 = folder / "fixes-ros2.csv"
    config = config_with(
        Path(args.config),
        f'[ros2]\ndomain_id = {args.domain}\ndiscovery = "localhost"\nfix_topic = "/fix"',
        folder,
    )
    log = open(folder / "ros2-fixes.log", "w+")
    proc = subprocess.Popen(
        [args.canodom, "ros2-fixes", "--config", str(config), "--out", str(via_ros2),
         "--count", str(len(fixes)), "--seconds", "60"],
        stderr=log,
    )
    dp = DomainParticipant(args.domain)
    writer = DataWriter(dp, Topic(dp, "rt/fix", NavSatFix), qos=ros2_qos(True, 100))
    until = time.monotonic() + 30
    while writer.get_publication_matched_status().current_count < 1 and time.monotonic() < until:
        time.sleep(0.05)
    time.sleep(0.3)
    for k, (sec, ns, lat, lon, alt) in enumerate(fixes):
        if k == 5:
            # A receiver without a fix (status -1): not a position, left out.
            writer.write(NavSatFix(
                header=Header(stamp=Time(sec=sec, nanosec=max(ns - 1000, 0)), frame_id="gnss"),
                status=NavSatStatus(status=-1, service=1),
                latitude=0.0, longitude=0.0, altitude=0.0,
                position_covariance=[0.0] * 9, position_covariance_type=0,
            ))
        writer.write(NavSatFix(
            header=Header(stamp=Time(sec=sec, nanosec=ns), frame_id="gnss"),
            status=NavSatStatus(status=0, service=1),
            latitude=lat, longitude=lon, altitude=alt,
            position_covariance=[0.25, 0, 0, 0, 0.25, 0, 0, 0, 1.0],
            position_covariance_type=2,
        ))
        time.sleep(0.005)
    try:
        proc.wait(timeout=60)
    except subprocess.TimeoutExpired:
        proc.kill()
    log.seek(0)
    print("\n== NavSatFix from Cyclone DDS to calibrate --fixes")
    for line in log.read().splitlines():
        if "ros2-fixes:" in line:
            print("   canodom:", line.strip())
    del writer, dp
    got = via_ros2.read_text() if via_ros2.exists() else ""
    want = direct.read_text()
    print(f"  {len(fixes)} fixes and one without a fix (status -1) published; the CSV written from ROS 2 "
          f"{'equals' if got == want else 'differs from'} the one written directly")
    if got != want:
        import difflib
        print("\n".join(list(difflib.unified_diff(want.splitlines(), got.splitlines(), "direct", "ros2",
                                                   lineterm=""))[:12]))
        failures.append("fixes: the CSV from ROS 2 differs from the fixes published")
        return failures
    # The drive's first 30 s, as the README's example calibrates it.
    first = folder / "first.log"
    with open(args.log) as src, first.open("w") as dst:
        for line in src:
            if float(line[1:18]) - t0 < 30:
                dst.write(line)
    estimates = []
    for name, fixes_csv in (("direct", direct), ("ros2", via_ros2), ("nmea", nmea)):
        out = subprocess.run(
            [args.canodom, "calibrate", "--config", str(d / "config_yaw.toml"), "--fixes",
             str(fixes_csv), "--out", str(folder / f"params-{name}.toml"), str(first)],
            capture_output=True, text=True,
        )
        if out.returncode != 0:
            failures.append(f"calibrate --fixes {name} exited {out.returncode}: {out.stderr[-2000:]}")
            return failures
        # The files' own names aside (each output names its parameter file).
        estimates.append(out.stdout.replace(str(fixes_csv), "FIXES")
                         .replace(f"params-{name}", "params"))
    # The NMEA file's report names its format where the CSV's names its columns.
    # The same fixes give the same estimate, to the last printed digit,
    # whichever way they came.
    for (name, other), label, ulps in (((0, 1), "the CSV written directly", 0),
                                       ((2, 1), "the NMEA file (GGA, GST, RMC)", 0)):
        a, b = (report_numbers(estimates[name]), report_numbers(estimates[other]))
        worst = last_digit_units(a, b)
        same = worst is not None and worst <= ulps and len(a) > 0
        if worst is not None:
            print(f"  largest difference from {label}: {worst} unit(s) of a figure's last printed digit")
        if not same:
            import difflib
            print("\n".join(difflib.unified_diff(
                estimates[name].splitlines(), estimates[other].splitlines(), "file", "ros2", lineterm="")))
        print(f"  calibrate --fixes: the estimate from ROS 2's fixes "
              f"{'is the same as' if same else 'differs from'} the one from {label} ({len(a)} figures compared)")
        if not same:
            failures.append(f"fixes: calibrate gives another estimate from ROS 2's fixes than from {label}")
    for line in estimates[1].splitlines()[:14]:
        print("   ", line)
    return failures


def nmea_grid(deg: float) -> float:
    """`deg` on NMEA's grid: whole degrees and minutes to 7 decimals."""
    sign, a = (-1.0 if deg < 0 else 1.0), abs(deg)
    d = int(a)
    return sign * (d + round((a - d) * 60.0, 7) / 60.0)


def nmea_sentence(body: str) -> str:
    check = 0
    for ch in body:
        check ^= ord(ch)
    return f"${body}*{check:02X}\r\n"


def nmea_epoch(sec: int, ns: int, lat: float, lon: float, alt: float, sigma_m: float) -> str:
    """GGA, GST (σ per axis) and RMC of one fix, as a receiver writes them."""
    when = time.gmtime(sec)
    hms = time.strftime("%H%M%S", when) + f".{ns // 10_000_000:02d}"
    date = time.strftime("%d%m%y", when)

    def dm(v: float, width: int, pos: str, neg: str) -> tuple:
        a = abs(v)
        d = int(a)
        return f"{d:0{width}d}{(a - d) * 60.0:010.7f}", pos if v >= 0 else neg

    la, ns_ = dm(lat, 2, "N", "S")
    lo, ew = dm(lon, 3, "E", "W")
    s = f"{sigma_m:.2f}"
    return "".join(nmea_sentence(b) for b in (
        f"GPGGA,{hms},{la},{ns_},{lo},{ew},1,09,0.9,{alt:.3f},M,0.0,M,,",
        f"GPGST,{hms},{sigma_m * 1.4142:.2f},{s},{s},0.0,{s},{s},{1.5 * sigma_m:.2f}",
        f"GPRMC,{hms},A,{la},{ns_},{lo},{ew},0.00,0.0,{date},,,A",
    ))


def last_digit_units(a: list, b: list):
    """The largest difference between two reports' figures in units of each
    figure's last printed digit; None when they do not pair up."""
    if len(a) != len(b):
        return None
    worst = 0
    for x, y in zip(a, b):
        places = len(x.split(".")[1].split("e")[0]) if "." in x else 0
        worst = max(worst, round(abs(float(x) - float(y)) * 10 ** places))
    return worst


def report_numbers(report: str) -> list:
    """The figures of a `calibrate` report, less the lines that name the fixes' file and format."""
    keep = [line for line in report.splitlines() if "FIXES" not in line and "NMEA" not in line
            and "CSV" not in line]
    return re.findall(r"[-+]?\d+(?:\.\d+)?(?:e[-+]?\d+)?", "\n".join(keep))


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--canodom", required=True, help="the canodom binary")
    p.add_argument("--config", required=True)
    p.add_argument("--log", required=True)
    p.add_argument("--domain", type=int, default=77, help="a DDS domain of the test's own")
    p.add_argument("--speed", type=float, default=1.0, help="the default-QoS run's pace")
    p.add_argument("--sensor-speed", type=float, default=2.0, help="the sensor-data run's pace")
    p.add_argument("--only", choices=("odom", "fixes", "graph"), action="append",
                   help="run only these checks (repeatable; default: all four)")
    args = p.parse_args()
    only = set(args.only or ("odom", "fixes", "graph"))
    failures = []
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d)
        if "odom" in only:
            rows = reference(args, folder)
            failures += run(args, "default", args.speed, rows, folder)
            failures += run(args, "sensor_data", args.sensor_speed, rows, folder)
        if "fixes" in only:
            failures += fixes_from_ros2(args, folder)
        if "graph" in only:
            failures += ros_graph(args, folder)
    print()
    for f in failures:
        print("FAIL:", f)
    checks = ("odom" in only) * 2 + ("fixes" in only) + ("graph" in only)
    print(f"{0 if failures else checks} passed, {1 if failures else 0} failed")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
