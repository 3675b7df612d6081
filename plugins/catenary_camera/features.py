"""Camera features by their GenICam standard names, the same for every backend.

A camera is configured through a :class:`FeatureAccess` (Aravis's camera, or the remote
device's node map of a GenTL producer). Each setting names its features in order of
preference, the Standard Features Naming Convention's current name first and the older
``...Abs`` name after it (``ExposureTime``, then ``ExposureTimeAbs``); the first one the
camera implements is set and read back. A camera that has none of them is one line naming
the camera and the names tried.

The line rate of a free-running line-scan camera is ``AcquisitionLineRate`` (or
``AcquisitionLineRateAbs``). A camera without either (an area-scan camera such as Aravis's
fake camera, whose frames are read as ``Height`` lines) is run at ``AcquisitionFrameRate`` =
line rate / ``Height``: the lines of a frame then come out at the line rate on average, not
one by one, which is how the fake camera was tested and only suitable for tests.
"""

from __future__ import annotations

import math
from typing import Protocol

from catenary.errors import UserError

from .settings import CameraSettings, GigeSettings

__all__ = ["FeatureAccess", "configure", "set_first"]

Value = int | float | str

EXPOSURE = ("ExposureTime", "ExposureTimeAbs")
LINE_RATE = ("AcquisitionLineRate", "AcquisitionLineRateAbs")
FRAME_RATE = ("AcquisitionFrameRate", "AcquisitionFrameRateAbs")
FRAME_RATE_ENABLE = ("AcquisitionFrameRateEnable", "AcquisitionFrameRateEnabled")
LINE_TRIGGER = "LineStart"  # the trigger of one line (SFNC TriggerSelector)
FRAME_TRIGGER = "FrameStart"


class FeatureAccess(Protocol):
    """A camera's features by name (a backend's adapter)."""

    def has(self, name: str) -> bool:
        """Whether the camera implements and currently offers ``name``."""
        ...

    def set(self, name: str, value: Value) -> None:
        """Set ``name`` (integer, float, boolean as int, or enumeration entry)."""
        ...

    def get(self, name: str) -> Value:
        """Read ``name`` back."""
        ...

    def entries(self, name: str) -> tuple[str, ...]:
        """The entries an enumeration ``name`` offers now."""
        ...


def set_first(
    access: FeatureAccess, names: tuple[str, ...], value: Value, device: str, what: str
) -> str:
    """Set the first of ``names`` the camera has to ``value`` and check it reads back.

    Returns the name used. ``UserError`` in one line if the camera has none of them or keeps
    another value (floats within 0.1 %: cameras round to their clock).
    """
    for name in names:
        if not access.has(name):
            continue
        access.set(name, value)
        back = access.get(name)
        same = (
            math.isclose(float(back), float(value), rel_tol=1e-3)
            if isinstance(value, float) and isinstance(back, int | float)
            else back == value
        )
        if not same:
            raise UserError(f"camera {device}: {name} set to {value!r} reads back {back!r}")
        return name
    raise UserError(f"camera {device}: no {what} feature ({' or '.join(names)})")


def _select_trigger(access: FeatureAccess, selector: str) -> bool:
    """Select ``TriggerSelector = selector`` if the camera offers it; whether it does."""
    if not access.has("TriggerSelector") or selector not in access.entries("TriggerSelector"):
        return False
    access.set("TriggerSelector", selector)
    return True


def configure(access: FeatureAccess, camera: CameraSettings, acquisition: GigeSettings) -> None:
    """Set a camera's region, pixel format, exposure and line trigger (module docstring).

    The backend sets what is transport-specific (packet size) itself.
    """
    device = camera.device
    if access.has("AcquisitionMode"):
        set_first(access, ("AcquisitionMode",), "Continuous", device, "acquisition mode")
    set_first(access, ("PixelFormat",), camera.pixel_format, device, "pixel format")
    # the offset to 0 before the width, then to its value: each must fit the sensor
    has_offset = access.has("OffsetX")
    if has_offset:
        set_first(access, ("OffsetX",), 0, device, "horizontal offset")
    set_first(access, ("Width",), camera.width, device, "width")
    if has_offset or camera.offset_px:
        set_first(access, ("OffsetX",), camera.offset_px, device, "horizontal offset")
    set_first(access, ("Height",), acquisition.lines_per_frame, device, "height (lines per frame)")
    if camera.exposure_us is not None:
        set_first(access, EXPOSURE, camera.exposure_us, device, "exposure time")
    if acquisition.trigger == "encoder":
        if not _select_trigger(access, LINE_TRIGGER):
            raise UserError(
                f"camera {device}: no line trigger (TriggerSelector entry {LINE_TRIGGER}) for "
                "trigger 'encoder'"
            )
        set_first(access, ("TriggerMode",), "On", device, "trigger mode")
        set_first(access, ("TriggerSource",), acquisition.trigger_line, device, "trigger source")
        if _select_trigger(access, FRAME_TRIGGER):  # a frame is every Height lines
            set_first(access, ("TriggerMode",), "Off", device, "trigger mode")
        return
    for selector in (LINE_TRIGGER, FRAME_TRIGGER):
        if _select_trigger(access, selector) and access.has("TriggerMode"):
            set_first(access, ("TriggerMode",), "Off", device, "trigger mode")
    rate = acquisition.line_rate_hz
    assert rate is not None  # parse_settings: trigger 'free' has a line rate
    if any(access.has(name) for name in LINE_RATE):
        set_first(access, LINE_RATE, rate, device, "line rate")
        return
    for name in FRAME_RATE_ENABLE:
        if access.has(name):
            access.set(name, 1)
            break
    set_first(access, FRAME_RATE, rate / acquisition.lines_per_frame, device, "line or frame rate")
