"""Aravis's fake GigE Vision cameras in the test process, with lines of our choosing.

``FakeCamera`` is an ``Aravis.GvFakeCamera`` listening on one loopback address (two cannot
share one: ``.ci/run`` adds 127.0.0.2-5 to ``lo``), run from a copy of Aravis's own GenICam
description whose ``Width`` and ``OffsetX`` go to 16384 (the shipped one stops at its 2048-px
sensor). Its frames are filled by a Python function through ``arv_fake_camera_set_fill_pattern``
called with ctypes (PyGObject's own binding frees the callback it is given, and the camera
then crashes): ``content(first_line, lines, width)`` returns the frame's lines ``[lines,
width]`` uint8, ``first_line`` being the frame's first line counted from the UNIX epoch at
the line rate. The fake camera stamps a frame with the host's time when its thread wakes,
late by a few ms on a busy machine (and tens of ms on this one, which the callbacks in this
process make busier).
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import multiprocessing
import os
import re
import signal
import subprocess
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from catenary_camera.aravis import load_aravis

Content = Callable[[int, int, int], np.ndarray]

ADDRESSES = ("127.0.0.2", "127.0.0.3", "127.0.0.4", "127.0.0.5")
MAX_WIDTH = 16384
_PR_SET_PDEATHSIG = 1  # prctl: the signal a process gets when its parent ends (Linux)
ACQUISITION_REGISTER = 0x124  # ARV_FAKE_CAMERA_REGISTER_ACQUISITION: 0 stops streaming

_FILL = ctypes.CFUNCTYPE(
    None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32, ctypes.c_uint32
)


def _library() -> ctypes.CDLL:
    lib = ctypes.CDLL("libaravis-0.8.so.0")
    lib.arv_fake_camera_set_fill_pattern.argtypes = [ctypes.c_void_p, _FILL, ctypes.c_void_p]
    lib.arv_fake_camera_set_fill_pattern.restype = None
    lib.arv_fake_camera_write_register.argtypes = [
        ctypes.c_void_p,
        ctypes.c_uint32,
        ctypes.c_uint32,
    ]
    lib.arv_fake_camera_write_register.restype = ctypes.c_int
    lib.arv_buffer_get_data.argtypes = [ctypes.c_void_p, ctypes.POINTER(ctypes.c_size_t)]
    lib.arv_buffer_get_data.restype = ctypes.c_void_p
    lib.arv_buffer_get_timestamp.argtypes = [ctypes.c_void_p]
    lib.arv_buffer_get_timestamp.restype = ctypes.c_uint64
    lib.arv_buffer_set_timestamp.argtypes = [ctypes.c_void_p, ctypes.c_uint64]
    lib.arv_buffer_set_timestamp.restype = None
    for name in ("arv_buffer_get_image_width", "arv_buffer_get_image_height"):
        getattr(lib, name).argtypes = [ctypes.c_void_p]
        getattr(lib, name).restype = ctypes.c_int
    return lib


_LIB = _library()
_GET_POINTER = ctypes.pythonapi.PyCapsule_GetPointer
_GET_POINTER.restype = ctypes.c_void_p
_GET_POINTER.argtypes = [ctypes.py_object, ctypes.c_char_p]


def missing_addresses() -> list[str]:
    """The loopback addresses the fake cameras need that ``lo`` lacks."""
    shown = subprocess.run(
        ["ip", "-4", "-o", "addr", "show", "dev", "lo"], capture_output=True, text=True
    ).stdout
    have = {line.split()[3].split("/")[0] for line in shown.splitlines() if "inet" in line}
    return [a for a in ADDRESSES if a not in have]


def wide_genicam(path: Path, line_trigger: bool = True) -> Path:
    """Aravis's fake camera description with ``Width`` and ``OffsetX`` up to 16384 and
    (``line_trigger``) a line-scan camera's ``LineStart`` trigger, at ``path``. The trigger's
    settings are only stored (the fake camera's registers hold them): with encoder
    triggering it sends its frames as a train at constant speed would have it, and stops
    them (:meth:`FakeCamera.stand`) as the train standing would."""
    aravis = load_aravis()
    xml = aravis.FakeCamera.new("xml").get_genicam_xml()
    text = xml[0] if isinstance(xml, tuple) else xml
    for name in ("Width", "OffsetX"):
        block = re.compile(rf'(<Integer Name="{name}".*?)<pMax>SensorWidth</pMax>', re.S)
        text, count = block.subn(rf"\1<Max>{MAX_WIDTH}</Max>", text, count=1)
        assert count == 1, name
    entry = '<EnumEntry Name="AcquisitionStart" NameSpace="Standard">'
    line_start = '<EnumEntry Name="LineStart" NameSpace="Standard"><Value>2</Value></EnumEntry>'
    assert text.count(entry) == 1
    if line_trigger:
        text = text.replace(entry, line_start + entry)
    path.write_text(text)
    return path


class FakeCamera:
    """One fake GigE Vision camera on ``address`` (module docstring)."""

    def __init__(self, address: str, serial: str, genicam: Path) -> None:
        aravis = load_aravis()
        self.address = address
        self.serial = serial
        self.camera: Any = aravis.GvFakeCamera.new_full(address, serial, str(genicam))
        if not self.camera.is_running():
            raise RuntimeError(f"fake camera on {address} did not start")
        fake = self.camera.get_fake_camera()
        self._pointer = _GET_POINTER(fake.__gpointer__, None)
        self._fake = fake
        self._callback: Any = None
        self._next_line: int | None = None
        self.frames = 0

    def set_loss(self, per_thousand: float) -> None:
        """Drop this share of the stream's packets (the ``-r`` of ``arv-fake-gv-camera``)."""
        self.camera.set_property("gvsp-lost-ratio", per_thousand / 1000.0)

    def fill(
        self, content: Content | None, rate_hz: float = 1.0, *, line_clock: bool = False
    ) -> None:
        """Fill frames with ``content`` (None: Aravis's own diagonal ramp) as a line-scan
        camera would: the lines go on from frame to frame, from those of the frame period
        (at ``rate_hz``, from the UNIX epoch) that the second frame's timestamp falls in.
        The fake camera sends its frames on that grid but its first one anywhere (it holds
        the lines of its own period; the gige source does not time by a first frame).
        ``line_clock``: each frame is stamped with its first line's time, as a camera's own
        line clock stamps it, instead of when the fake camera's thread woke (late by up to
        tens of ms on this busy machine: module docstring)."""
        if content is None:
            _LIB.arv_fake_camera_set_fill_pattern(self._pointer, _FILL(), None)
            self._callback = None
            return

        def fill(buffer: int, data: int, exposure: int, gain: int, pixel_format: int) -> None:
            width = _LIB.arv_buffer_get_image_width(buffer)
            height = _LIB.arv_buffer_get_image_height(buffer)
            if self.frames < 2:  # the lines of the frame period it falls in
                stamped = _LIB.arv_buffer_get_timestamp(buffer) * 1e-9 * rate_hz
                self._next_line = int(stamped // height) * height
            assert self._next_line is not None
            first, self._next_line = self._next_line, self._next_line + height
            if line_clock:
                _LIB.arv_buffer_set_timestamp(buffer, round(first / rate_hz * 1e9))
            lines = np.ascontiguousarray(content(first, height, width), dtype=np.uint8)
            target = _LIB.arv_buffer_get_data(buffer, None)
            ctypes.memmove(target, lines.ctypes.data, min(lines.nbytes, width * height))
            self.frames += 1

        self._callback = _FILL(fill)  # kept: the camera calls it until replaced
        _LIB.arv_fake_camera_set_fill_pattern(self._pointer, self._callback, None)

    def stand(self, standing: bool) -> None:
        """Stop sending frames, the camera still answering, or go on (an encoder-triggered
        camera while the train stands, and when it moves again): its frame ids and lines go
        on from where they stopped."""
        _LIB.arv_fake_camera_write_register(self._pointer, ACQUISITION_REGISTER, int(not standing))

    def close(self) -> None:
        """Stop the camera (its thread and sockets go with the object). No full garbage
        collection: the other fake cameras fill their frames in Python, and one (0.2-0.8 s
        on a busy machine, Python's lock held) stalled them up to 0.94 s; a fake camera held
        past its next frame periods skips them without counting its frame id on, so the
        lines ``fill`` counts on sat 1-2 frames before the stamps the recorder places them
        by. Dropping the object joins the camera's thread (its polls last 0.1 s at most)."""
        self.stand(True)
        time.sleep(0.5)  # the frame under way is sent; then the camera streams no more
        self.fill(None)  # no Python callback may run while the camera is finalised
        self.camera = self._fake = None


def _serve(
    address: str, serial: str, genicam: str, rate_hz: float, go: Any, ready: Any, parent: int
) -> None:
    """A ``CameraProcess``'s body: once ``go`` is set, a fake camera filled with marked lines
    at ``rate_hz``, until the process is killed, or its parent ends (however it ends: a
    camera left behind would answer on its address in the next test). At real-time priority
    where allowed (as root): a camera has its own line clock, which nothing on the host
    delays."""
    ctypes.CDLL(None).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # it ended before the line above
        return
    with contextlib.suppress(PermissionError):  # its threads, created after, inherit it
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(10))
    go.wait()
    camera = FakeCamera(address, serial, Path(genicam))
    camera.fill(marked_lines, rate_hz)
    ready.set()
    threading.Event().wait()


class CameraProcess:
    """A fake camera filled with ``marked_lines`` in a process of its own: ``kill`` ends it
    as a camera losing its power would, with nothing more on the wire. The process starts
    (Python, NumPy, Aravis loaded) when made and the camera when ``start`` is called."""

    def __init__(self, address: str, serial: str, genicam: Path, rate_hz: float) -> None:
        context = multiprocessing.get_context("spawn")
        self.address = address
        self._go, self._ready = context.Event(), context.Event()
        self._process = context.Process(
            target=_serve,
            args=(address, serial, str(genicam), rate_hz, self._go, self._ready, os.getpid()),
            name=f"fake camera {address}",
            daemon=True,
        )
        self._process.start()

    def start(self, timeout_s: float = 60.0) -> None:
        """Start the camera; return once it streams."""
        self._go.set()
        if not self._ready.wait(timeout_s):
            raise RuntimeError(
                f"fake camera on {self.address} did not start "
                f"(its process's exit code {self._process.exitcode})"
            )

    def kill(self) -> None:
        self._process.kill()
        self._process.join()


@functools.cache
def _ramps(width: int) -> np.ndarray:
    """``(m + x) % 251`` for every ``m`` in 0..250 and pixel ``x`` (``[251, width]`` uint8)."""
    return ((np.arange(251)[:, None] + np.arange(width)[None, :]) % 251).astype(np.uint8)


def marked_lines(first: int, lines: int, width: int) -> np.ndarray:
    """Lines that say which they are: line ``L`` holds ``L % 2**32`` (little-endian, 4
    bytes) then ``(L % 2**32 + x) % 251`` at pixel ``x``; ``[lines, width]`` uint8. Quick
    (a table's rows): the fake camera stamps a frame before filling it and sends it after."""
    index = np.arange(first, first + lines, dtype=np.int64) % 2**32
    out = _ramps(width)[index % 251]
    out[:, :4] = index.astype("<u4").view(np.uint8).reshape(lines, 4)
    return out


def line_marks(lines: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mark ``L`` of each line ``[n, W]`` and whether the rest of it agrees ``[n]``."""
    marks = np.ascontiguousarray(lines[:, :4]).view("<u4")[:, 0].astype(np.int64)
    width = lines.shape[1]
    expected = (marks[:, None] + np.arange(4, width)[None, :]) % 251
    return marks, (lines[:, 4:] == expected).all(axis=1)
