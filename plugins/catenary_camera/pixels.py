"""Camera buffers to lines: the monochrome pixel formats of GenICam and GigE Vision, unpacked.

Pure: bytes in, NumPy out, vectorised over the pixels (a Python loop over at most the eight
pixels of a packing group, never over pixels). Every layout below is little-endian, and the
lines of a buffer follow one another without padding, so in a packed format a line of an odd
number of pixels (or, for ``Mono10p``, of a width that is not a multiple of four) ends
mid-byte and the next line starts there.

=================  =====  ===================================================================
format             bits   layout
=================  =====  ===================================================================
``Mono8``          8      one byte per pixel
``Mono10``         10     unpacked: one little-endian 16-bit word per pixel, the value in its
``Mono12``         12     low bits (GenICam PFNC: "Mono10", "Mono12", "Mono16")
``Mono16``         16
``Mono10p``        10     PFNC bit-packed, LSB first: the pixels' bits follow one another in
``Mono12p``        12     a little-endian bit stream, pixel ``k`` at bits ``k * bits`` up;
                          ``Mono12p``: byte 0 = p0[7:0], byte 1 = p1[3:0] p0[11:8] (high
                          nibble first as written), byte 2 = p1[11:4]; ``Mono10p``: 4 pixels
                          in 5 bytes, byte 1 = p1[5:0] p0[9:8], ... byte 4 = p3[9:2]
``Mono10Packed``   10     GigE Vision's own packing (GigE Vision 1.x/2.x, before the PFNC):
``Mono12Packed``   12     2 pixels in 3 bytes; ``Mono12Packed``: byte 0 = p0[11:4], byte 1 =
                          p1[3:0] p0[3:0], byte 2 = p1[11:4]; ``Mono10Packed``: byte 0 =
                          p0[9:2], byte 1 = 0 0 p1[1:0] 0 0 p0[1:0], byte 2 = p1[9:2]. An
                          odd pixel at the end of a buffer takes bytes 0 and 1 of a group
=================  =====  ===================================================================

(``p0[11:8]`` are bits 11 to 8 of pixel 0; in a byte the high bits are written first.)

Sources: the GenICam Pixel Format Naming Convention (PFNC 2.x, section "packed" formats,
LSB-first bit order, values ``Mono10p = 0x010A0046``, ``Mono12p = 0x010C0047``) and the
GigE Vision specification's pixel formats appendix ("Mono10Packed", ``0x010C0004``;
"Mono12Packed", ``0x010C0006``, "the first pixel of the second line will not start on a
3-byte boundary when the width is odd"), as summarised in the vendors' SDK documentation
(Basler pylon ``PixelType``: "the memory layouts of Mono10packed and Mono10p are
different"; Allied Vision Vimba ``VmbPixelFormatType``: Mono12Packed "2x12 bits in 24 bits
(GEV)"); the Linux V4L2 documents of the same 3-byte layouts were used to check the byte
order.
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np

from catenary.arrays import UInt8Array, UInt16Array

__all__ = ["PIXEL_FORMATS", "buffer_bytes", "unpack_lines"]

PIXEL_FORMATS: Final[dict[str, int]] = {
    "Mono8": 8,
    "Mono10": 10,
    "Mono12": 12,
    "Mono16": 16,
    "Mono10p": 10,
    "Mono12p": 12,
    "Mono10Packed": 10,
    "Mono12Packed": 12,
}
"""The pixel formats read, by their GenICam names, to their bit depth."""

_UNPACKED: Final = frozenset({"Mono10", "Mono12", "Mono16"})
_PFNC_PACKED: Final = frozenset({"Mono10p", "Mono12p"})
_GIGE_PACKED: Final = frozenset({"Mono10Packed", "Mono12Packed"})


def _container_bits(pixel_format: str) -> int:
    """Bits a pixel takes in the buffer."""
    if pixel_format == "Mono8":
        return 8
    if pixel_format in _UNPACKED:
        return 16
    if pixel_format in _GIGE_PACKED:
        return 12
    return PIXEL_FORMATS[pixel_format]


def buffer_bytes(pixel_format: str, width: int, lines: int) -> int:
    """The bytes of ``lines`` lines of ``width`` pixels in ``pixel_format`` (lines
    contiguous, a trailing partial byte counted)."""
    _check(pixel_format, width)
    return -(-lines * width * _container_bits(pixel_format) // 8)


def _check(pixel_format: str, width: int) -> None:
    if pixel_format not in PIXEL_FORMATS:
        raise ValueError(
            f"unknown pixel format {pixel_format!r} (known: {', '.join(PIXEL_FORMATS)})"
        )
    if isinstance(width, bool) or not isinstance(width, int | np.integer) or width < 1:
        raise ValueError(f"{pixel_format}: width must be a positive integer, got {width!r}")


def unpack_lines(
    data: bytes | bytearray | memoryview | np.ndarray[Any, Any], pixel_format: str, width: int
) -> UInt8Array | UInt16Array:
    """The lines held by a camera buffer, ``[lines, width]``.

    Parameters
    ----------
    data : bytes-like or ndarray
        The buffer's image data (its bytes, whatever an array's dtype), lines contiguous.
    pixel_format : str
        A key of :data:`PIXEL_FORMATS` (module docstring).
    width : int
        Pixels per line.

    Returns a new array (never a view of ``data``): uint8 for ``Mono8``, else uint16 holding
    the pixel values (0 to ``2**bits - 1`` for the packed formats; the unpacked ones are
    returned as sent). A buffer that is not a whole number of lines (by
    :func:`buffer_bytes`), or an unknown format, raises ``ValueError`` naming the format and
    the sizes.
    """
    _check(pixel_format, width)
    if isinstance(data, np.ndarray):
        raw = np.ascontiguousarray(data).reshape(-1).view(np.uint8)
    else:
        raw = np.frombuffer(data, dtype=np.uint8)
    bits = _container_bits(pixel_format)
    lines = raw.shape[0] * 8 // (width * bits)
    if buffer_bytes(pixel_format, width, lines) != raw.shape[0]:
        raise ValueError(
            f"{pixel_format}: a buffer of {raw.shape[0]} bytes is not a whole number of lines "
            f"of {width} pixels ({width * bits} bits each)"
        )
    pixels = lines * width
    if pixel_format == "Mono8":
        return raw.reshape(lines, width).copy()
    if pixel_format in _UNPACKED:
        return raw.view("<u2").astype(np.uint16).reshape(lines, width)
    if pixel_format in _PFNC_PACKED:
        values = _unpack_lsb_first(raw, PIXEL_FORMATS[pixel_format])
    else:
        values = _unpack_gige(raw, PIXEL_FORMATS[pixel_format])
    return values[:pixels].reshape(lines, width)


def _whole_groups(raw: UInt8Array, group_bytes: int) -> UInt8Array:
    """``raw``, zero-padded to whole groups of ``group_bytes`` (copied only then)."""
    short = -raw.shape[0] % group_bytes
    if short == 0:
        return raw
    return np.concatenate((raw, np.zeros(short, dtype=np.uint8)))


def _words(raw: UInt8Array, offset: int, stride: int, count: int) -> UInt16Array:
    """The little-endian 16-bit words at bytes ``offset + i * stride`` of ``raw``, ``[count]``
    (a strided view, unaligned: no copy)."""
    return np.ndarray((count,), dtype="<u2", buffer=raw, offset=offset, strides=(stride,))


def _unpack_lsb_first(raw: UInt8Array, bits: int) -> UInt16Array:
    """PFNC LSB-first bit packing: groups of 8 pixels in ``bits`` bytes; ``[8 * groups]``.
    Pixel ``k`` of a group is the 16-bit word at its first byte, shifted and masked (its
    ``shift + bits`` is at most 16 for 10 and 12 bits)."""
    group = _whole_groups(raw, bits)
    count = group.shape[0] // bits
    out = np.empty((count, 8), dtype=np.uint16)
    mask = (1 << bits) - 1
    for k in range(8):
        first, shift = divmod(k * bits, 8)
        word = _words(group, first, bits, count)
        np.bitwise_and(np.right_shift(word, shift), mask, out=out[:, k])
    return out.reshape(-1)


def _unpack_gige(raw: UInt8Array, bits: int) -> UInt16Array:
    """GigE Vision Mono10Packed / Mono12Packed: 2 pixels in 3 bytes; ``[2 * groups]``."""
    group = _whole_groups(raw, 3).reshape(-1, 3)
    low = bits - 8
    mask = (1 << low) - 1
    out = np.empty((group.shape[0], 2), dtype=np.uint16)
    high = np.left_shift(group[:, 0], low, dtype=np.uint16)
    np.bitwise_or(high, group[:, 1] & mask, out=out[:, 0])
    high = np.left_shift(group[:, 2], low, dtype=np.uint16)
    np.bitwise_or(high, (group[:, 1] >> 4) & mask, out=out[:, 1])
    return out.reshape(-1)
