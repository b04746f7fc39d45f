"""rmw_zenoh's publication attachment: sequence number, source timestamp and the publisher's GID.

rmw_zenoh_cpp (rmw_zenoh_cpp/src/detail/attachment_helpers.cpp at commit
534747dca92adf15e1b1b975123037ca278db5ba, and rmw_publisher_data.cpp, which puts it on every
publication) writes it with zenoh-cpp's ``ext::Serializer``: the sequence number (int64, from 1
per publisher), the source timestamp (int64, system time in ns), then the 16-byte GID as a
``std::array``, which zenoh's serialisation format writes as a sequence: its length as a LEB128
varint (one byte, 16) and the bytes. Integers are little-endian. So: 8 + 8 + 1 + 16 = 33 bytes.

Earlier rmw_zenoh releases on zenoh-c 1.0 (attachment_helpers.cpp at
038b5a4fbb337e8033a7474a4a788fa381204c3c) put each value after its name as a string
(``sequence_number``, ``source_timestamp``, ``source_gid``; a string is its varint length and its
UTF-8 bytes). Decoding accepts both; encoding writes the current form.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

from zenslam.errors import MessageError

GID_SIZE = 16  # RMW_GID_STORAGE_SIZE
_INT64 = struct.Struct("<q")
_KEYS = ("sequence_number", "source_timestamp", "source_gid")


@dataclass(frozen=True)
class Attachment:
    """What rmw_zenoh attaches to a publication."""

    sequence_number: int  # 1, 2, ... per publisher
    source_timestamp_ns: int  # the publisher's system time at publication, ns since the epoch
    source_gid: bytes  # the publisher's 16-byte GID

    def __post_init__(self) -> None:
        if len(self.source_gid) != GID_SIZE:
            raise MessageError(f"a ROS 2 GID has {GID_SIZE} bytes, got {len(self.source_gid)}")


def encode_attachment(attachment: Attachment) -> bytes:
    """The attachment's bytes as rmw_zenoh_cpp writes them (the current, key-less form)."""
    return (
        _INT64.pack(attachment.sequence_number)
        + _INT64.pack(attachment.source_timestamp_ns)
        + bytes([GID_SIZE])
        + bytes(attachment.source_gid)
    )


class _Reader:
    def __init__(self, data: bytes):
        self.data, self.at = data, 0

    def take(self, n: int) -> bytes:
        if self.at + n > len(self.data):
            raise MessageError(f"rmw_zenoh attachment of {len(self.data)} bytes ends early (needs {self.at + n})")
        chunk = self.data[self.at : self.at + n]
        self.at += n
        return chunk

    def varint(self) -> int:
        value, shift = 0, 0
        while True:
            byte = self.take(1)[0]
            value |= (byte & 0x7F) << shift
            if byte < 0x80:
                return value
            shift += 7
            if shift > 63:
                raise MessageError("rmw_zenoh attachment has a malformed length")

    def int64(self) -> int:
        return _INT64.unpack(self.take(8))[0]

    def sequence(self) -> bytes:
        return self.take(self.varint())


def _decode_keyed(reader: _Reader) -> Attachment:
    values: list[object] = []
    for key in _KEYS:
        name = reader.sequence()
        if name != key.encode():
            raise MessageError(f"rmw_zenoh attachment has {name[:32]!r} where {key!r} should be")
        values.append(reader.sequence() if key == "source_gid" else reader.int64())
    return Attachment(int(values[0]), int(values[1]), bytes(values[2]))  # type: ignore[arg-type]


def decode_attachment(data: bytes | bytearray | memoryview | None) -> Attachment:
    """The Attachment in ``data`` (either form); MessageError when there is none or it is malformed."""
    if data is None:
        raise MessageError("the publication has no attachment: rmw_zenoh attaches one to every message")
    data = bytes(data)
    keyed = data.startswith(bytes([len(_KEYS[0])]) + _KEYS[0].encode())
    reader = _Reader(data)
    if keyed:
        attachment = _decode_keyed(reader)
    else:
        sequence_number, timestamp = reader.int64(), reader.int64()
        attachment = Attachment(sequence_number, timestamp, reader.sequence())
    if reader.at != len(data):
        raise MessageError(f"rmw_zenoh attachment has {len(data) - reader.at} bytes after its end")
    return attachment
