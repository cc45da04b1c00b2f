#!/usr/bin/env python3
"""Rewrites a laser bag with tools nobody on mapmerge wrote, for issue 19's independent checks.

Reads IN.mcap (LaserScan, Odometry, TFMessage; e.g. from `mapmerge convert`) with `mcap` +
`mcap-ros2-support`, which decode by the file's own message definitions, then writes the same
messages four times:

  OUT/rosbags-mcap/      a rosbag2 bag directory, MCAP storage, by `rosbags`
  OUT/rosbags-db3/       a rosbag2 bag directory, SQLite storage, by `rosbags`
  OUT/mcap-ros2.mcap     one MCAP file by `mcap-ros2-support`'s writer, with the message
                         definitions `rosbags` generates (not the input's), zstd chunks
  OUT/mcap-ros2-lz4.mcap the same with lz4 chunks

Every message is rebuilt field by field from the decoded values and serialised by each tool's
own CDR encoder, so mapmerge reading these bags back checks its decoder against independent
encoders, and its writer against an independent decoder.

usage: bag_interop.py IN.mcap OUT_DIR
"""

import sys
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType
from mcap_ros2.decoder import DecoderFactory
from mcap_ros2.writer import Writer as McapRos2Writer
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

STORE = get_typestore(Stores.ROS2_HUMBLE)
T = STORE.types


def time(t):
    return T["builtin_interfaces/msg/Time"](sec=t.sec, nanosec=t.nanosec)


def header(h):
    return T["std_msgs/msg/Header"](stamp=time(h.stamp), frame_id=h.frame_id)


def vector3(v, kind="geometry_msgs/msg/Vector3"):
    return T[kind](x=v.x, y=v.y, z=v.z)


def quaternion(q):
    return T["geometry_msgs/msg/Quaternion"](x=q.x, y=q.y, z=q.z, w=q.w)


def laser_scan(m):
    return T["sensor_msgs/msg/LaserScan"](
        header=header(m.header),
        angle_min=m.angle_min,
        angle_max=m.angle_max,
        angle_increment=m.angle_increment,
        time_increment=m.time_increment,
        scan_time=m.scan_time,
        range_min=m.range_min,
        range_max=m.range_max,
        ranges=np.asarray(m.ranges, dtype=np.float32),
        intensities=np.asarray(m.intensities, dtype=np.float32),
    )


def odometry(m):
    pose = T["geometry_msgs/msg/Pose"](
        position=vector3(m.pose.pose.position, "geometry_msgs/msg/Point"),
        orientation=quaternion(m.pose.pose.orientation),
    )
    twist = T["geometry_msgs/msg/Twist"](
        linear=vector3(m.twist.twist.linear), angular=vector3(m.twist.twist.angular)
    )
    return T["nav_msgs/msg/Odometry"](
        header=header(m.header),
        child_frame_id=m.child_frame_id,
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=pose, covariance=np.asarray(m.pose.covariance, dtype=np.float64)
        ),
        twist=T["geometry_msgs/msg/TwistWithCovariance"](
            twist=twist, covariance=np.asarray(m.twist.covariance, dtype=np.float64)
        ),
    )


def tf_message(m):
    return T["tf2_msgs/msg/TFMessage"](
        transforms=[
            T["geometry_msgs/msg/TransformStamped"](
                header=header(t.header),
                child_frame_id=t.child_frame_id,
                transform=T["geometry_msgs/msg/Transform"](
                    translation=vector3(t.transform.translation),
                    rotation=quaternion(t.transform.rotation),
                ),
            )
            for t in m.transforms
        ]
    )


REBUILD = {
    "sensor_msgs/msg/LaserScan": laser_scan,
    "nav_msgs/msg/Odometry": odometry,
    "tf2_msgs/msg/TFMessage": tf_message,
}


def as_dict(message):
    """A rosbags message as nested dicts and lists, for mcap-ros2-support's encoder."""
    if hasattr(message, "__dataclass_fields__"):
        return {k: as_dict(getattr(message, k)) for k in message.__dataclass_fields__ if k != "__msgtype__"}
    if isinstance(message, np.ndarray):
        return message.tolist()
    if isinstance(message, list):
        return [as_dict(m) for m in message]
    return message


def read(path):
    """(topic, type, log_time_ns, rebuilt message) of every message, in file order."""
    out = []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            rebuild = REBUILD.get(schema.name)
            if rebuild is None:
                raise SystemExit(f"{path}: unexpected message type {schema.name}")
            out.append((channel.topic, schema.name, message.log_time, rebuild(decoded)))
    return out


def write_rosbags(messages, path, storage):
    with Writer(path, version=9, storage_plugin=storage) as writer:
        connections = {}
        for topic, msgtype, log_time, message in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=STORE)
            writer.write(connections[topic], log_time, STORE.serialize_cdr(message, msgtype))


def write_mcap_ros2(messages, path, compression):
    with open(path, "wb") as f:
        writer = McapRos2Writer(f, compression=compression)
        schemas = {}
        for topic, msgtype, log_time, message in messages:
            if msgtype not in schemas:
                text, _ = STORE.generate_msgdef(msgtype, ros_version=2)
                schemas[msgtype] = writer.register_msgdef(msgtype, text)
            writer.write_message(topic, schemas[msgtype], as_dict(message), log_time=log_time)
        writer.finish()


def main():
    if len(sys.argv) != 3:
        raise SystemExit(__doc__)
    source, out = Path(sys.argv[1]), Path(sys.argv[2])
    out.mkdir(parents=True, exist_ok=True)
    messages = read(source)
    write_rosbags(messages, out / "rosbags-mcap", StoragePlugin.MCAP)
    write_rosbags(messages, out / "rosbags-db3", StoragePlugin.SQLITE3)
    write_mcap_ros2(messages, out / "mcap-ros2.mcap", CompressionType.ZSTD)
    write_mcap_ros2(messages, out / "mcap-ros2-lz4.mcap", CompressionType.LZ4)
    print(f"{len(messages)} messages from {source} rewritten into {out}")


if __name__ == "__main__":
    main()
