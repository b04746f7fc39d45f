"""rmw_zenoh's attachment, checked against bytes made by zenoh's own serializer (zenoh.ext)."""

from __future__ import annotations

import pytest
from zenoh.ext import Int64, z_serialize

from zenslam.errors import MessageError
from zenslam.service.ros2.attachment import Attachment, decode_attachment, encode_attachment

GID = bytes(range(100, 116))


def test_encoding_is_zenohs_serialisation_of_int64_int64_and_a_16_byte_sequence():
    # zenoh-cpp serialises rmw_zenoh's std::array<uint8_t, 16> as a sequence, as zenoh.ext does bytes.
    expected = z_serialize((Int64(42), Int64(-5), GID)).to_bytes()
    assert len(expected) == 33
    assert encode_attachment(Attachment(42, -5, GID)) == expected
    assert decode_attachment(expected) == Attachment(42, -5, GID)


def test_the_keyed_form_of_earlier_releases_decodes():
    keyed = z_serialize(("sequence_number", Int64(7), "source_timestamp", Int64(1_700_000_000_000_000_000), "source_gid", GID))
    assert decode_attachment(keyed.to_bytes()) == Attachment(7, 1_700_000_000_000_000_000, GID)


@pytest.mark.parametrize(
    "data",
    [None, b"", bytes(16), bytes(17) + b"\x0f" + bytes(15), encode_attachment(Attachment(1, 2, GID)) + b"\x00",
     b"\x0fsequence_number" + bytes(8) + b"\x03abc"],
)
def test_malformed_attachments_raise_message_error(data):
    with pytest.raises(MessageError):
        decode_attachment(data)
