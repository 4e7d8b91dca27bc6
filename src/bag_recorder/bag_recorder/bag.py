"""Bags of a running graph: rosbag2 folders with MCAP storage (library core, no ROS).

Written with rosbags (pure Python, on PyPI): it writes the rosbag2 layout itself, ``metadata.yaml``
beside ``<name>.mcap``, so ``ros2 bag info`` / ``ros2 bag play``, Foxglove and PlotJuggler open a
bag unchanged, and it carries the definitions of the standard ROS 2 Jazzy messages. Types it does
not know (the stack's gait_msgs) come from their installed ``.msg`` files. Messages are stored as
the CDR bytes that arrived, stamped with their receive time [ns] on the recorder's clock.

MCAP keeps messages in chunks of about 1 MiB; each is in the file once written. A recorder that is
killed leaves no ``metadata.yaml`` and no index, but every chunk written before stays readable
(``read_mcap_messages``; on a full ROS install ``ros2 bag reindex`` rebuilds the metadata).
"""

from __future__ import annotations

import os
import struct
from collections.abc import Iterator
from pathlib import Path

from a1_common.config import ConfigError
from mcap.exceptions import McapError
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from rosbags.interfaces import Nodetype, Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import Reader, StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

BAG_VERSION = 9  # rosbag2's metadata version in Jazzy


def register_installed(store, msgtypes: list[str]) -> None:
    """Add to ``store`` every type of ``msgtypes`` it lacks, from the installed .msg files
    (``share/<package>/msg/<Name>.msg`` under AMENT_PREFIX_PATH), with the types they use."""
    pending = [t for t in msgtypes if t not in store.fielddefs]
    found: dict = {}
    while pending:
        msgtype = pending.pop()
        if msgtype in found or msgtype in store.fielddefs:
            continue
        types = get_types_from_msg(_msg_file(msgtype).read_text(), msgtype)
        found.update(types)
        pending += [name for _, fields in types.values() for _, fielddef in fields
                    if (name := _referenced_type(fielddef)) and name not in store.fielddefs]
    if found:
        store.register(found)


def _referenced_type(fielddef: tuple) -> str | None:
    """The message type a field holds (also as array or sequence elements), None for a base type."""
    kind, ref = fielddef
    if kind == Nodetype.NAME:
        return ref
    if kind in (Nodetype.ARRAY, Nodetype.SEQUENCE):
        return _referenced_type(ref[0])
    return None


def _msg_file(msgtype: str) -> Path:
    package, _, name = msgtype.split("/")
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        path = Path(prefix) / "share" / package / "msg" / f"{name}.msg"
        if path.is_file():
            return path
    raise ConfigError(f"no message definition for {msgtype}: share/{package}/msg/{name}.msg is not under "
                      "AMENT_PREFIX_PATH (source scripts/env.sh)")


def qos_of(history: int, depth: int, reliability: int, durability: int) -> Qos:
    """A publisher's QoS as rosbag2 stores it (``ros2 bag play`` offers it again); the policy numbers
    are rmw's, which rclpy's enums and rosbags' share."""
    never = QosTime(0x7FFFFFFF, 0xFFFFFFFF)  # rmw's infinite duration
    return Qos(QosHistory(history), depth, QosReliability(reliability), QosDurability(durability), never, never,
               QosLiveliness.AUTOMATIC, never, False)


class BagWriter:
    """One rosbag2 folder being written: ``add_topic`` before its first ``write``, ``close`` at the end."""

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise ConfigError(f"bag folder {self.path} already exists; choose another (rosbag2 never overwrites)")
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self._writer.open()
        self._connections: dict[str, object] = {}
        self._typestore = get_typestore(Stores.ROS2_JAZZY)  # one for the bag, grown as topics come
        self.counts: dict[str, int] = {}

    def add_topic(self, topic: str, msgtype: str, qos: list[Qos] | None = None) -> None:
        register_installed(self._typestore, [msgtype])
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._typestore, offered_qos_profiles=qos or [])
        self.counts[topic] = 0

    def has_topic(self, topic: str) -> bool:
        return topic in self._connections

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self._writer.write(self._connections[topic], stamp_ns, data)
        self.counts[topic] += 1

    def close(self) -> None:
        """Write the last chunk, the index and metadata.yaml (idempotent)."""
        if self._writer is not None:
            self._writer.close()
            self._writer = None


def read_bag(path: str | os.PathLike) -> Iterator[tuple[str, str, int, bytes]]:
    """(topic, type, receive time [ns], CDR bytes) of every message of a closed bag, in time order."""
    with Reader(Path(path)) as reader:
        for connection, stamp_ns, data in reader.messages():
            yield connection.topic, connection.msgtype, stamp_ns, bytes(data)


def read_mcap_messages(path: str | os.PathLike) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log time [ns], CDR bytes) of a bag's .mcap read front to back, up to the last complete
    record: what a killed recorder's file still holds (it has no index to seek with)."""
    mcap_files = sorted(Path(path).glob("*.mcap"))
    if not mcap_files:
        raise ConfigError(f"{path}: no .mcap file in the bag folder")
    channels: dict[int, str] = {}
    with mcap_files[0].open("rb") as stream:
        try:
            for record in StreamReader(stream).records:  # chunks come out as the records inside them
                if isinstance(record, Channel):
                    channels[record.id] = record.topic
                elif isinstance(record, Message):
                    yield channels[record.channel_id], record.log_time, record.data
        except (McapError, EOFError, struct.error):  # the record the kill cut short
            return
