"""Camera buffers unpacked: byte buffers laid out by hand from the pixel-format standards
(GenICam PFNC, GigE Vision), then round trips through packers written from the same tables."""

from __future__ import annotations

import numpy as np
import pytest

from catenary_camera.pixels import PIXEL_FORMATS, buffer_bytes, unpack_lines


def pack_lsb_first(values: np.ndarray, bits: int) -> bytes:
    """PFNC ``MonoNp``: pixel ``k`` at bits ``k * bits`` of one little-endian bit stream."""
    stream = sum(int(v) << (k * bits) for k, v in enumerate(values.reshape(-1)))
    return stream.to_bytes(-(-values.size * bits // 8), "little")


def pack_gige(values: np.ndarray, bits: int) -> bytes:
    """GigE Vision ``MonoNPacked`` from its byte table; an odd last pixel takes two bytes."""
    low = bits - 8
    mask = (1 << low) - 1
    flat = [int(v) for v in values.reshape(-1)]
    out = bytearray()
    for i in range(0, len(flat), 2):
        p0 = flat[i]
        out += bytes([p0 >> low])
        if i + 1 == len(flat):
            out += bytes([p0 & mask])
            break
        p1 = flat[i + 1]
        out += bytes([((p1 & mask) << 4) | (p0 & mask), p1 >> low])
    return bytes(out)


def test_mono8_and_unpacked_words() -> None:
    lines = unpack_lines(bytes([1, 2, 3, 250, 251, 252]), "Mono8", 3)
    assert lines.dtype == np.uint8
    np.testing.assert_array_equal(lines, [[1, 2, 3], [250, 251, 252]])
    # Mono12: little-endian 16-bit words, 0x0ABC then 0x0123
    lines = unpack_lines(bytes([0xBC, 0x0A, 0x23, 0x01]), "Mono12", 2)
    assert lines.dtype == np.uint16
    np.testing.assert_array_equal(lines, [[0x0ABC, 0x0123]])
    np.testing.assert_array_equal(unpack_lines(bytes([0xFF, 0xFF]), "Mono16", 1), [[65535]])


def test_mono12p_by_hand() -> None:
    # p0 = 0xABC = 1010 1011 1100, p1 = 0x123 = 0001 0010 0011 (LSB first):
    # byte 0 = p0[7:0]  = 1011 1100 = 0xBC
    # byte 1 = p1[3:0] p0[11:8] = 0011 1010 = 0x3A
    # byte 2 = p1[11:4] = 0001 0010 = 0x12
    lines = unpack_lines(bytes([0xBC, 0x3A, 0x12]), "Mono12p", 2)
    np.testing.assert_array_equal(lines, [[0xABC, 0x123]])


def test_mono10p_by_hand() -> None:
    # p0 = 0x3FF, p1 = 0x001, p2 = 0x200, p3 = 0x155 (01 0101 0101), LSB first:
    # byte 0 = p0[7:0]           = 1111 1111
    # byte 1 = p1[5:0] p0[9:8]   = 000001 11 = 0x07
    # byte 2 = p2[3:0] p1[9:6]   = 0000 0000
    # byte 3 = p3[1:0] p2[9:4]   = 01 100000 = 0x60
    # byte 4 = p3[9:2]           = 0101 0101 = 0x55
    lines = unpack_lines(bytes([0xFF, 0x07, 0x00, 0x60, 0x55]), "Mono10p", 4)
    np.testing.assert_array_equal(lines, [[0x3FF, 0x001, 0x200, 0x155]])


def test_mono12packed_by_hand() -> None:
    # GigE Vision: byte 0 = p0[11:4], byte 1 = p1[3:0] p0[3:0], byte 2 = p1[11:4]
    # p0 = 0xABC, p1 = 0x123: 0xAB, 0x3C, 0x12
    lines = unpack_lines(bytes([0xAB, 0x3C, 0x12]), "Mono12Packed", 2)
    np.testing.assert_array_equal(lines, [[0xABC, 0x123]])


def test_mono10packed_by_hand() -> None:
    # GigE Vision 2.x: byte 0 = p0[9:2], byte 1 = 00 p1[1:0] 00 p0[1:0], byte 2 = p1[9:2]
    # p0 = 0x2FE = 10 1111 1110, p1 = 0x0C1 = 00 1100 0001:
    # 1011 1111 = 0xBF, 00 01 00 10 = 0x12, 0011 0000 = 0x30
    lines = unpack_lines(bytes([0xBF, 0x12, 0x30]), "Mono10Packed", 2)
    np.testing.assert_array_equal(lines, [[0x2FE, 0x0C1]])


def test_the_two_10_bit_packings_differ() -> None:
    data = bytes([0xBF, 0x12, 0x30])
    assert not np.array_equal(
        unpack_lines(data, "Mono10Packed", 2), unpack_lines(data + b"\0\0", "Mono10p", 4)[:, :2]
    )


@pytest.mark.parametrize("width", [1, 3, 4, 7, 8, 2051])
@pytest.mark.parametrize("pixel_format", ["Mono10p", "Mono12p", "Mono10Packed", "Mono12Packed"])
def test_round_trip_lines_contiguous(pixel_format: str, width: int) -> None:
    """Odd widths included: a line then ends mid-byte (or mid-group) and the next starts
    there."""
    bits = PIXEL_FORMATS[pixel_format]
    rng = np.random.default_rng(width)
    values = rng.integers(0, 1 << bits, size=(5, width), dtype=np.uint16)
    values[0, 0] = (1 << bits) - 1
    pack = pack_lsb_first if pixel_format.endswith("p") else pack_gige
    data = pack(values, bits)
    assert len(data) == buffer_bytes(pixel_format, width, 5)
    lines = unpack_lines(data, pixel_format, width)
    assert lines.dtype == np.uint16
    np.testing.assert_array_equal(lines, values)
    # a memoryview and an array of the same bytes read the same
    np.testing.assert_array_equal(unpack_lines(memoryview(data), pixel_format, width), values)
    array = np.frombuffer(data, dtype=np.uint8)
    np.testing.assert_array_equal(unpack_lines(array, pixel_format, width), values)


def test_unpacked_formats_round_trip_and_copy() -> None:
    values = np.arange(12, dtype=np.uint16).reshape(3, 4) * 300
    data = bytearray(values.astype("<u2").tobytes())
    lines = unpack_lines(data, "Mono12", 4)
    np.testing.assert_array_equal(lines, values)
    eight = bytearray(range(12))
    mono8 = unpack_lines(eight, "Mono8", 4)
    eight[0] = 99  # the buffer is requeued and refilled: the lines must not change
    data[0] = 99
    assert mono8[0, 0] == 0 and lines[0, 0] == 0


@pytest.mark.parametrize(
    ("pixel_format", "width", "size"),
    [("Mono8", 4, 7), ("Mono12", 3, 7), ("Mono12", 3, 4), ("Mono12p", 2, 4), ("Mono10p", 4, 6)],
)
def test_a_buffer_of_part_lines_is_refused(pixel_format: str, width: int, size: int) -> None:
    with pytest.raises(ValueError, match=rf"{pixel_format}: a buffer of {size} bytes"):
        unpack_lines(bytes(size), pixel_format, width)


def test_unknown_format_and_bad_width() -> None:
    with pytest.raises(ValueError, match=r"unknown pixel format 'Mono14'.*Mono12Packed"):
        unpack_lines(b"", "Mono14", 4)
    with pytest.raises(ValueError, match=r"Mono8: width must be a positive integer, got 0"):
        unpack_lines(b"", "Mono8", 0)


def test_bit_depths() -> None:
    assert PIXEL_FORMATS == {
        "Mono8": 8,
        "Mono10": 10,
        "Mono12": 12,
        "Mono16": 16,
        "Mono10p": 10,
        "Mono12p": 12,
        "Mono10Packed": 10,
        "Mono12Packed": 12,
    }
