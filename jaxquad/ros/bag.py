"""Opening ROS 1 and ROS 2 bags with rosbags (no ROS installation), and the typestores they need.

The kind comes from the path: a `.bag` file is ROS 1; a folder with `metadata.yaml`, or a bare
`.mcap` / `.db3` file, is ROS 2.
"""

from __future__ import annotations

import contextlib
import os
import struct
from collections.abc import Iterator
from pathlib import Path


def bag_kind(path: str | os.PathLike) -> str:
    """'ros1' or 'ros2' from the path (see the module doc), or a one-line error."""
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"bag not found: {path}")
    if path.is_file() and path.suffix == ".bag":
        return "ros1"
    if (path.is_dir() and (path / "metadata.yaml").is_file()) or (path.is_file() and path.suffix in (".mcap", ".db3")):
        return "ros2"
    raise ValueError(
        f"{path}: not a bag (expected a ROS 1 .bag file, or a ROS 2 folder with metadata.yaml, .mcap or .db3)"
    )


def typestore(kind: str, types: dict[str, str] | None = None):
    """The standard message types of ROS 1 Noetic or the latest ROS 2 LTS, plus `types` (name -> .msg text)."""
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore
    from rosbags.typesys.base import TypesysError

    store = get_typestore(Stores.ROS1_NOETIC if kind == "ros1" else Stores.LATEST)
    defs = {}
    for name in ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage"):  # TF messages, absent from rosbags' Noetic store
        if name not in store.fielddefs:
            defs.update(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", name))
    for name, text in (types or {}).items():
        try:
            defs.update(get_types_from_msg(text, name))
        except TypesysError as e:
            raise ValueError(f"message definition {name}: cannot be parsed ({str(e).splitlines()[0]})") from None
    if defs:
        store.register(defs)
    return store


@contextlib.contextmanager
def open_bag(path: str | os.PathLike, types: dict[str, str] | None = None) -> Iterator:
    """An open rosbags AnyReader; types missing from the bag's own definitions come from `types`
    and the standard store."""
    from rosbags.highlevel import AnyReader, AnyReaderError

    path = Path(path)
    store = typestore(bag_kind(path), types)
    try:
        reader = AnyReader([path], default_typestore=store)
        reader.open()
    except AnyReaderError as e:
        raise ValueError(f"bag {path}: cannot be read ({e})") from None
    try:
        known = reader.typestore.fielddefs
        extra = {k: v for k, v in store.fielddefs.items() if k not in known}
        if extra:
            reader.typestore.register(extra)
        yield reader
    finally:
        reader.close()


def topic_connections(reader, path, topic: str, role: str, want_type: str | None):
    """The bag's connections of `topic`, checked to exist, to carry `want_type` and to be decodable."""
    conns = [c for c in reader.connections if c.topic == topic]
    if not conns:
        have = ", ".join(f"{t} ({i.msgtype})" for t, i in sorted(reader.topics.items()))
        raise ValueError(f"bag {path}: topic {topic!r} ({role}) not found; the bag has: {have}")
    msgtype = conns[0].msgtype
    if want_type is not None and want_type != msgtype:
        raise ValueError(f"bag {path}: topic {topic!r} ({role}) carries {msgtype}, the topics file says {want_type}")
    if msgtype not in reader.typestore.fielddefs:
        raise ValueError(
            f"bag {path}: message type {msgtype} of {topic!r} ({role}) is unknown: the bag has no "
            f"definition for it; list its .msg file under 'types' in the topics file"
        )
    return conns


def messages(reader, path, conns) -> Iterator[tuple[object, int, object]]:
    """(connection, receive time ns, decoded message) over `conns`, in bag order."""
    from rosbags.highlevel import AnyReaderError

    for conn, t_ns, raw in reader.messages(connections=conns):
        try:
            msg = reader.deserialize(raw, conn.msgtype)
        except (AnyReaderError, ValueError, IndexError, struct.error, UnicodeDecodeError) as e:  # a wrong .msg
            raise ValueError(
                f"bag {path}: a {conn.msgtype} message on {conn.topic!r} cannot be decoded ({e})"
            ) from None
        yield conn, t_ns, msg
