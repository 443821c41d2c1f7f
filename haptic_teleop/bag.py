"""Compatibility re-exports of haptic_teleop.record (the recording layer); use haptic_teleop.record."""

from haptic_teleop.record.layouts import (
    JOINT_STATE,
    MULTIARRAY,
    PACKET_BATCH,
    PACKET_FIELDS,
    STRING,
    WRENCH,
    FixedLayout,
    TopicSpec,
    joint_state_size,
    make_joint_state,
    make_multiarray,
    make_wrench,
    multiarray_bytes,
    packet_batch_bytes,
    packet_rows,
    string_bytes,
    topic_specs,
    typestore,
)
from haptic_teleop.record.mcap import BagSink
from haptic_teleop.record.metadata import yaml_block
from haptic_teleop.record.reader import BagReader, TopicData
from haptic_teleop.record.recorder import RunRecorder, write_run
from haptic_teleop.record.streams import BLOCK_TICKS, RunStreams, Stream

# Older private names some modules and tests import.
_packet_rows = packet_rows
_multiarray_bytes = multiarray_bytes
_packet_batch_bytes = packet_batch_bytes
_string_bytes = string_bytes
_yaml_block = yaml_block
_BagSink = BagSink
_Stream = Stream

__all__ = [
    "BLOCK_TICKS",
    "JOINT_STATE",
    "MULTIARRAY",
    "PACKET_BATCH",
    "PACKET_FIELDS",
    "STRING",
    "WRENCH",
    "BagReader",
    "BagSink",
    "FixedLayout",
    "RunRecorder",
    "RunStreams",
    "Stream",
    "TopicData",
    "TopicSpec",
    "_BagSink",
    "_Stream",
    "_multiarray_bytes",
    "_packet_batch_bytes",
    "_packet_rows",
    "_string_bytes",
    "_yaml_block",
    "joint_state_size",
    "make_joint_state",
    "make_multiarray",
    "make_wrench",
    "multiarray_bytes",
    "packet_batch_bytes",
    "packet_rows",
    "string_bytes",
    "topic_specs",
    "typestore",
    "write_run",
    "yaml_block",
]
