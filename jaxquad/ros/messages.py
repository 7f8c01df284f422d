"""Building and writing standard ROS messages with rosbags, for ROS 1 and ROS 2 alike."""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path

import numpy as np

from jaxquad.ros.bag import typestore

FORMATS = ("mcap", "sqlite3", "ros1")


class Messages:
    """Message constructors of one typestore (ROS 1 headers carry `seq`, ROS 2 ones do not)."""

    def __init__(self, kind: str, types: dict[str, str] | None = None):
        self.kind, self.store = kind, typestore(kind, types)
        self.types = self.store.types
        self._seq = "seq" in dict(self.store.fielddefs["std_msgs/msg/Header"][1])

    def time(self, t_ns: int | np.integer):
        return self.types["builtin_interfaces/msg/Time"](
            sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000)
        )

    def header(self, t_ns: int | np.integer, frame: str):
        extra = {"seq": 0} if self._seq else {}
        return self.types["std_msgs/msg/Header"](**extra, stamp=self.time(t_ns), frame_id=frame)

    def vector3(self, v, name: str = "Vector3"):
        return self.types[f"geometry_msgs/msg/{name}"](x=float(v[0]), y=float(v[1]), z=float(v[2]))

    def quaternion(self, q_wxyz):
        w, x, y, z = (float(c) for c in q_wxyz)
        return self.types["geometry_msgs/msg/Quaternion"](x=x, y=y, z=z, w=w)

    def pose(self, p, q_wxyz):
        return self.types["geometry_msgs/msg/Pose"](
            position=self.vector3(p, "Point"), orientation=self.quaternion(q_wxyz)
        )

    def transform(self, t_ns: int | np.integer, parent: str, child: str, p, q_wxyz):
        tf = self.types["geometry_msgs/msg/Transform"](translation=self.vector3(p), rotation=self.quaternion(q_wxyz))
        return self.types["geometry_msgs/msg/TransformStamped"](
            header=self.header(t_ns, parent), child_frame_id=child, transform=tf
        )

    def serialize(self, msg, msgtype: str) -> bytes:
        ser = self.store.serialize_ros1 if self.kind == "ros1" else self.store.serialize_cdr
        return bytes(ser(msg, msgtype))


def seconds_to_ns(t: np.ndarray) -> np.ndarray:
    return np.round(np.asarray(t, np.float64) * 1e9).astype(np.int64)


class BagWriter:
    """Writes (topic, type, t_ns, message) into a ROS 1 bag or a ROS 2 bag (mcap or sqlite3)."""

    def __init__(self, writer, msgs: Messages):
        self.writer, self.msgs, self.conns = writer, msgs, {}

    def write(self, topic: str, msgtype: str, t_ns: int | np.integer, msg) -> None:
        if topic not in self.conns:
            self.conns[topic] = self.writer.add_connection(topic, msgtype, typestore=self.msgs.store)
        self.writer.write(self.conns[topic], int(t_ns), self.msgs.serialize(msg, msgtype))


@contextlib.contextmanager
def bag_writer(path: str | os.PathLike, fmt: str, types: dict[str, str] | None = None) -> Iterator[BagWriter]:
    """A BagWriter on `path` (which must not exist): a .bag file for 'ros1', else a ROS 2 folder."""
    if fmt not in FORMATS:
        raise ValueError(f"bag format {fmt!r} is not one of {', '.join(FORMATS)}")
    if fmt == "ros1":
        from rosbags.rosbag1 import Writer as Writer1

        writer = Writer1(Path(path))
    else:
        from rosbags.rosbag2 import StoragePlugin
        from rosbags.rosbag2 import Writer as Writer2

        plugin = StoragePlugin.MCAP if fmt == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(Path(path), version=9, storage_plugin=plugin)
    with writer:
        yield BagWriter(writer, Messages("ros1" if fmt == "ros1" else "ros2", types))
