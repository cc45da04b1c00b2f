#!/usr/bin/env python3
"""The other side of mapmerge's live ROS 2 nodes, on an independent DDS: Eclipse Cyclone DDS's
Python binding (`cyclonedds` on PyPI), with ROS 2's topic names (`rt/...`) and type names
(`pkg::msg::dds_::Type_`). The Rust tests of `mapmerge ros2` run it.

  play BAG     publish a bag's LaserScan, Odometry and TF in real time (times --rate), and
               record /map (the last one, as map_server YAML + PGM) and /tf map -> odom (the
               time from each scan's publication to its pose's arrival)
  maps R=YAML  publish map_server maps as /<R>/map (latched, as a robot's SLAM does), and
               record /map and /mapmerge/events

Exit code 0 when a map was received, 1 otherwise, 2 on bad arguments.
"""

import argparse
import json
import lzma
import pathlib
import sys
import time
from dataclasses import dataclass, field

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import array, float32, float64, int8, int32, sequence, uint32
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32 = 0
    nanosec: uint32 = 0


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header
    angle_min: float32
    angle_max: float32
    angle_increment: float32
    time_increment: float32
    scan_time: float32
    range_min: float32
    range_max: float32
    ranges: sequence[float32]
    intensities: sequence[float32]


@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: float64 = 0.0
    y: float64 = 0.0
    z: float64 = 0.0
    w: float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Vector3 = field(default_factory=Vector3)
    orientation: Quaternion = field(default_factory=Quaternion)


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
class MapMetaData(IdlStruct, typename="nav_msgs::msg::dds_::MapMetaData_"):
    map_load_time: Time
    resolution: float32
    width: uint32
    height: uint32
    origin: Pose


@dataclass
class OccupancyGrid(IdlStruct, typename="nav_msgs::msg::dds_::OccupancyGrid_"):
    header: Header
    info: MapMetaData
    data: sequence[int8]


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str


RELIABLE = Policy.Reliability.Reliable(max_blocking_time=duration(seconds=1))


def qos(latched=False, depth=1000):
    policies = [RELIABLE, Policy.History.KeepLast(depth)]
    if latched:
        policies.append(Policy.Durability.TransientLocal)
    return Qos(*policies)


def taken(reader, kind):
    """The valid samples waiting on `reader` (Cyclone also returns InvalidSample markers)."""
    return [s for s in reader.take(N=1000) if isinstance(s, kind)]


def time_of(t):
    return Time(sec=int(t.sec), nanosec=int(t.nanosec))


def header_of(h):
    return Header(stamp=time_of(h.stamp), frame_id=str(h.frame_id))


def vector_of(v):
    return Vector3(x=float(v.x), y=float(v.y), z=float(v.z))


def quaternion_of(q):
    return Quaternion(x=float(q.x), y=float(q.y), z=float(q.z), w=float(q.w))


def pose_of(p):
    return Pose(position=vector_of(p.position), orientation=quaternion_of(p.orientation))


def scan_of(m):
    return LaserScan(
        header=header_of(m.header),
        angle_min=m.angle_min,
        angle_max=m.angle_max,
        angle_increment=m.angle_increment,
        time_increment=m.time_increment,
        scan_time=m.scan_time,
        range_min=m.range_min,
        range_max=m.range_max,
        ranges=[float(r) for r in m.ranges],
        intensities=[float(i) for i in m.intensities],
    )


def odometry_of(m):
    return Odometry(
        header=header_of(m.header),
        child_frame_id=str(m.child_frame_id),
        pose=PoseWithCovariance(pose=pose_of(m.pose.pose), covariance=[float(c) for c in m.pose.covariance]),
        twist=TwistWithCovariance(
            twist=Twist(linear=vector_of(m.twist.twist.linear), angular=vector_of(m.twist.twist.angular)),
            covariance=[float(c) for c in m.twist.covariance],
        ),
    )


def tf_of(m):
    return TFMessage(
        transforms=[
            TransformStamped(
                header=header_of(t.header),
                child_frame_id=str(t.child_frame_id),
                transform=Transform(
                    translation=vector_of(t.transform.translation),
                    rotation=quaternion_of(t.transform.rotation),
                ),
            )
            for t in m.transforms
        ]
    )


def save_map(grid, yaml_path):
    """A received OccupancyGrid as map_server writes it (trinary PGM: 0 occupied, 254 free,
    205 unknown; the top row first)."""
    width, height = grid.info.width, grid.info.height
    pixel = {100: 0, 0: 254}
    rows = []
    data = grid.data
    for row in range(height - 1, -1, -1):
        cells = data[row * width:(row + 1) * width]
        rows.append(bytes(pixel.get(v, 205) for v in cells))
    yaml_path = pathlib.Path(yaml_path)
    pgm = yaml_path.with_suffix(".pgm")
    pgm.write_bytes(b"P5\n%d %d\n255\n" % (width, height) + b"".join(rows))
    o = grid.info.origin.position
    yaml_path.write_text(
        f"image: {pgm.name}\nresolution: {grid.info.resolution!r}\n"
        f"origin: [{o.x!r}, {o.y!r}, 0.0]\nnegate: 0\noccupied_thresh: 0.65\nfree_thresh: 0.196\n"
    )


def read_map(yaml_path):
    """A map_server map (YAML + binary PGM, `.xz` accepted) as an OccupancyGrid message, with
    map_server's trinary reading."""
    yaml_path = pathlib.Path(yaml_path)
    fields = {}
    for line in yaml_path.read_text().splitlines():
        if ":" in line:
            key, value = line.split(":", 1)
            fields[key.strip()] = value.strip()
    image = yaml_path.parent / fields["image"]
    if not image.exists() and image.with_name(image.name + ".xz").exists():
        image = image.with_name(image.name + ".xz")
    raw = image.read_bytes()
    if raw[:6] == b"\xfd7zXZ\x00":
        raw = lzma.decompress(raw)
    tokens, position = [], 0
    while len(tokens) < 4:
        while raw[position:position + 1].isspace():
            position += 1
        if raw[position:position + 1] == b"#":
            position = raw.index(b"\n", position)
            continue
        end = position
        while not raw[end:end + 1].isspace():
            end += 1
        tokens.append(raw[position:end])
        position = end
    if tokens[0] != b"P5":
        raise SystemExit(f"{image}: not a binary PGM")
    width, height, maxval = int(tokens[1]), int(tokens[2]), int(tokens[3])
    pixels = raw[position + 1:position + 1 + width * height]
    negate = fields.get("negate", "0") not in ("0", "false")
    occupied, free = float(fields.get("occupied_thresh", 0.65)), float(fields.get("free_thresh", 0.196))
    data = []
    for row in range(height - 1, -1, -1):
        for v in pixels[row * width:(row + 1) * width]:
            v = 255 - v if negate else v
            p = (maxval - v) / maxval
            data.append(100 if p > occupied else 0 if p < free else -1)
    origin = [float(x) for x in fields["origin"].strip("[]").split(",")]
    info = MapMetaData(
        map_load_time=Time(),
        resolution=float(fields["resolution"]),
        width=width,
        height=height,
        origin=Pose(position=Vector3(x=origin[0], y=origin[1])),
    )
    return OccupancyGrid(header=Header(frame_id="map"), info=info, data=data)


def wait_for_readers(writers, seconds):
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        if all(len(w.get_matched_subscriptions()) > 0 for w in writers):
            return True
        time.sleep(0.05)
    return False


def play(args):
    from mcap_ros2.reader import read_ros2_messages

    dp = DomainParticipant(args.domain)
    scan_w = DataWriter(dp, Topic(dp, "rt/scan", LaserScan), qos=qos())
    odom_w = DataWriter(dp, Topic(dp, "rt/odom", Odometry), qos=qos())
    tf_w = DataWriter(dp, Topic(dp, "rt/tf", TFMessage), qos=qos(depth=100))
    static_w = DataWriter(dp, Topic(dp, "rt/tf_static", TFMessage), qos=qos(latched=True, depth=1))
    map_r = DataReader(dp, Topic(dp, "rt/map", OccupancyGrid), qos=qos(latched=True, depth=1))
    tf_r = DataReader(dp, Topic(dp, "rt/tf", TFMessage), qos=qos(depth=1000))
    if not wait_for_readers([scan_w, odom_w], args.wait):
        print("no node subscribed to /scan and /odom", file=sys.stderr)
        return 1
    # Matched here is not yet matched there: the node's readers may still be taking in this
    # participant's writers, and a volatile sample before that is lost (the first odometry,
    # once, on freiburg-campus).
    time.sleep(1.0)
    messages = list(read_ros2_messages(args.bag))
    rate = args.rate
    if args.scan_hz:
        stamps = [m.log_time_ns / 1e9 for m in messages if m.channel.topic == "/scan"]
        if len(stamps) > 1 and stamps[-1] > stamps[0]:
            rate = args.scan_hz * (stamps[-1] - stamps[0]) / (len(stamps) - 1)
    published_at = {}
    arrived = {}
    maps = []

    def listen():
        for m in taken(tf_r, TFMessage):
            now = time.monotonic()
            for t in m.transforms:
                if t.child_frame_id != "odom" or t.header.frame_id != "map":
                    continue
                key = (t.header.stamp.sec, t.header.stamp.nanosec)
                arrived.setdefault(key, now)
        for m in taken(map_r, OccupancyGrid):
            maps.append((time.monotonic(), m))

    start_wall, start_log = time.monotonic(), None
    for message in messages:
        stamp = message.log_time_ns / 1e9
        start_log = stamp if start_log is None else start_log
        due = start_wall + (stamp - start_log) / rate
        while True:
            listen()
            wait = due - time.monotonic()
            if wait <= 0:
                break
            time.sleep(min(wait, 0.002))
        topic, ros = message.channel.topic, message.ros_msg
        if topic == "/scan":
            scan = scan_of(ros)
            published_at[(scan.header.stamp.sec, scan.header.stamp.nanosec)] = time.monotonic()
            scan_w.write(scan)
        elif topic == "/odom":
            odom_w.write(odometry_of(ros))
        elif topic == "/tf_static":
            static_w.write(tf_of(ros))
        elif topic == "/tf":
            tf_w.write(tf_of(ros))
    played = time.monotonic()
    if args.played:
        pathlib.Path(args.played).touch()
    # The node publishes its last map after the scans have stopped, then leaves: its map
    # writer unmatched means every map it sent is here.
    while time.monotonic() < played + args.linger:
        listen()
        if maps and not map_r.get_matched_publications():
            break
        time.sleep(0.05)
    listen()
    latencies = [1e3 * (arrived[k] - t) for k, t in published_at.items() if k in arrived]
    report = {
        "scans_published": len(published_at),
        "poses_received": len(latencies),
        "latency_ms": sorted(latencies),
        "maps_received": len(maps),
        "play_seconds": played - start_wall,
        "rate": rate,
    }
    if maps:
        save_map(maps[-1][1], args.map_out)
        report["map"] = str(args.map_out)
    pathlib.Path(args.report).write_text(json.dumps(report))
    return 0 if maps else 1


def publish_maps(args):
    dp = DomainParticipant(args.domain)
    writers = []
    for pair in args.robots:
        name, _, yaml = pair.partition("=")
        if not name or not yaml:
            print(f"robot '{pair}': give NAME=MAP.yaml", file=sys.stderr)
            return 2
        writer = DataWriter(dp, Topic(dp, f"rt/{name}/map", OccupancyGrid), qos=qos(latched=True, depth=1))
        writer.write(read_map(yaml))
        writers.append(writer)
    map_r = DataReader(dp, Topic(dp, "rt/map", OccupancyGrid), qos=qos(latched=True, depth=1))
    events_r = DataReader(dp, Topic(dp, "rt/mapmerge/events", String), qos=qos(latched=True, depth=100))
    end = time.monotonic() + args.seconds
    maps, events = [], []
    while time.monotonic() < end:
        maps.extend(taken(map_r, OccupancyGrid))
        events.extend(json.loads(s.data) for s in taken(events_r, String))
        time.sleep(0.05)
    report = {"maps_received": len(maps), "events": events}
    if maps:
        save_map(maps[-1], args.map_out)
        report["map"] = str(args.map_out)
    pathlib.Path(args.report).write_text(json.dumps(report))
    return 0 if maps else 1


def main():
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--domain", type=int, default=0)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("play")
    p.add_argument("bag")
    p.add_argument("--rate", type=float, default=1.0, help="times real time")
    p.add_argument("--scan-hz", type=float, help="instead of --rate: scans this often on average")
    p.add_argument("--wait", type=float, default=30.0, help="seconds to wait for the node")
    p.add_argument("--linger", type=float, default=60.0, help="seconds to wait for the last map")
    p.add_argument("--played", help="a file touched once every message is out")
    p.add_argument("--map-out", required=True)
    p.add_argument("--report", required=True)
    m = sub.add_parser("maps")
    m.add_argument("robots", nargs="+", help="NAME=MAP.yaml")
    m.add_argument("--seconds", type=float, default=30.0)
    m.add_argument("--map-out", required=True)
    m.add_argument("--report", required=True)
    args = parser.parse_args()
    return play(args) if args.command == "play" else publish_maps(args)


if __name__ == "__main__":
    sys.exit(main())
