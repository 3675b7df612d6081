"""Settings of the ``gige`` scan source: the rig's cameras and how their lines are triggered.

Keys of the source's settings (``--source-option KEY=VALUE`` or ``[record] source_options``):

=======================  =====================================================================
``cameras``              a table of the rig's cameras by name (the calibration's names), each a
                         table of the camera keys below (required, at least one)
``backend``              ``aravis`` (GigE Vision through Aravis) or ``gentl`` (a vendor's GenTL
                         producer through harvesters: frame grabbers, cameras) (``aravis``)
``cti``                  backend ``gentl``: the GenTL producer, a ``.cti`` file or a list of
                         them (default: every ``.cti`` file in the folders that the standard
                         variable ``GENICAM_GENTL64_PATH`` lists, separated by ``:``)
``trigger``              ``free`` (free-running at ``line_rate_hz``) or ``encoder`` (the wheel
                         encoder on the hardware line ``trigger_line``) (``free``)
``line_rate_hz``         free-running line rate [Hz] (required with ``trigger = "free"``)
``trigger_line``         the camera input the encoder drives (``Line0``)
``metres_per_line``      encoder distance between two lines [m] (required with ``encoder``)
``lines_per_frame``      lines per camera frame (the camera's ``Height``) (256)
``buffers``              frame buffers queued per camera (32)
``timeout_s``            a camera that delivers nothing this long is taken as dropped off and
                         reconnected [s] (2.0); with ``encoder`` trigger, when none of them
                         has, the train stands, and only a camera that answers no register
                         read is (``catenary_camera.stream``, Standing)
``reconnect_interval_s`` the wait between reconnection attempts [s] (1.0)
``synchronized_clocks``  the cameras' timestamps are on one clock (IEEE 1588 PTP, GigE Vision
                         2): frames are placed by them, every camera alike (false: each
                         camera's clock is mapped to the host's by its frames' arrival, which
                         aligns the cameras only to within their network latencies' spread)
``arrival_lag_frames``   the least time from a frame's first line to its arrival at the host, in
                         frame periods (``lines_per_frame`` lines at ``nominal_rate_hz``): a
                         camera's clock is mapped to the host's by its frames' quickest
                         arrivals, and a camera sends a frame once its lines are all taken (1;
                         0 for a camera that sends a frame's leader as its first line is
                         taken, as Aravis's fake camera does)
``nominal_rate_hz``      the run header's ``scan_rate_hz`` with ``encoder`` trigger (line rate
                         at the line speed; default: ``line_rate_hz`` if given, else 1000)
``line``, ``track``, ``vehicle``  run identifiers (``""``)
``direction``            ``increasing`` or ``decreasing`` chainage (``increasing``)
``start_chainage_m``     chainage at the first scan (0)
=======================  =====================================================================

Camera keys (in ``cameras.NAME``; ``pixel_format``, ``exposure_us`` and ``packet_size`` may
also be given at the top level as the default of every camera):

=======================  =====================================================================
``address``              backend ``aravis``: the camera's IP address or host name; or
``serial``               its serial number (found by discovery); or
``device_id``            backend ``gentl``: the device's id in its GenTL producer
``width``                pixels per line recorded (required)
``offset_px``            the first sensor pixel recorded (a region of interest) (0)
``pixel_format``         ``Mono8``, ``Mono10``, ``Mono12``, ``Mono16``, ``Mono10p``,
                         ``Mono12p``, ``Mono10Packed``, ``Mono12Packed`` (``Mono8``)
``exposure_us``          exposure time [µs] (default: the camera's own setting)
``packet_size``          GigE Vision stream packet size [bytes] (default: the camera's; backend
                         ``gentl``: the device's ``GevSCPSPacketSize``)
=======================  =====================================================================

Every error names the key and the value in one line (:class:`~catenary.errors.UserError`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

from catenary.errors import UserError

__all__ = ["BACKENDS", "CameraSettings", "GigeSettings", "parse_settings"]

BACKENDS: Final = ("aravis", "gentl")
GENTL_PATH_VARIABLE: Final = "GENICAM_GENTL64_PATH"
TRIGGERS: Final = ("free", "encoder")
CAMERA_KEYS: Final = frozenset(
    {
        "address",
        "serial",
        "device_id",
        "width",
        "offset_px",
        "pixel_format",
        "exposure_us",
        "packet_size",
    }
)
DEVICE_KEYS: Final = {"aravis": ("address", "serial"), "gentl": ("serial", "device_id")}
"""The keys that name a camera's device, by backend."""
SHARED_CAMERA_KEYS: Final = frozenset({"pixel_format", "exposure_us", "packet_size"})
TOP_KEYS: Final = frozenset(
    {
        "cameras",
        "backend",
        "cti",
        "trigger",
        "line_rate_hz",
        "trigger_line",
        "metres_per_line",
        "lines_per_frame",
        "buffers",
        "timeout_s",
        "reconnect_interval_s",
        "synchronized_clocks",
        "arrival_lag_frames",
        "nominal_rate_hz",
        "line",
        "track",
        "vehicle",
        "direction",
        "start_chainage_m",
    }
    | SHARED_CAMERA_KEYS
)
_SOURCE = "source 'gige'"


@dataclass(frozen=True)
class CameraSettings:
    """One rig camera: the device (``address``, ``serial`` or ``device_id``) and its
    acquisition."""

    name: str
    address: str | None
    serial: str | None
    width: int
    offset_px: int
    pixel_format: str
    exposure_us: float | None
    packet_size: int | None
    device_id: str | None = None

    @property
    def device(self) -> str:
        """How the camera is named in messages (``cam1 (127.0.0.2)``, ``cam1 (serial 0)``,
        ``cam1 (id VikyTL_DEV_red)``)."""
        if self.address is not None:
            return f"{self.name} ({self.address})"
        if self.device_id is not None:
            return f"{self.name} (id {self.device_id})"
        return f"{self.name} (serial {self.serial})"


@dataclass(frozen=True)
class GigeSettings:
    """Validated settings of the ``gige`` source (module docstring)."""

    cameras: tuple[CameraSettings, ...]
    backend: str = "aravis"
    cti: tuple[str, ...] = ()  # backend gentl: the GenTL producers' files
    trigger: str = "free"
    line_rate_hz: float | None = None
    trigger_line: str = "Line0"
    metres_per_line: float | None = None
    lines_per_frame: int = 256
    buffers: int = 32
    timeout_s: float = 2.0
    reconnect_interval_s: float = 1.0
    synchronized_clocks: bool = False
    arrival_lag_frames: float = 1.0
    nominal_rate_hz: float = 1000.0
    line: str = ""
    track: str = ""
    vehicle: str = ""
    direction: str = "increasing"
    start_chainage_m: float = 0.0

    @property
    def frame_period_s(self) -> float:
        """Nominal time between two frames of a camera [s] (``lines_per_frame`` lines)."""
        return self.lines_per_frame / self.nominal_rate_hz


def _bad(key: str, value: object, expected: str) -> UserError:
    return UserError(f"{_SOURCE}: setting {key} = {value!r}: expected {expected}")


def _positive(key: str, value: object, *, integer: bool = False) -> Any:
    kinds = int if integer else (int, float)
    if isinstance(value, bool) or not isinstance(value, kinds):
        raise _bad(key, value, "a positive integer" if integer else "a positive number")
    assert isinstance(value, int | float)
    if not (math.isfinite(value) and value > 0):
        raise _bad(key, value, "a positive integer" if integer else "a positive number")
    return value


def _text(key: str, value: object) -> str:
    if not isinstance(value, str) or not value.strip() or value != value.strip():
        raise _bad(key, value, "a non-empty string without surrounding spaces")
    return value


def _camera(name: str, table: object, defaults: Mapping[str, Any], backend: str) -> CameraSettings:
    from catenary_camera.pixels import PIXEL_FORMATS

    where = f"cameras.{name}"
    if not isinstance(table, Mapping):
        raise _bad(where, table, "a table of camera settings")
    unknown = sorted(set(table) - CAMERA_KEYS)
    if unknown:
        raise UserError(
            f"{_SOURCE}: unknown setting {where}.{unknown[0]} "
            f"(known: {', '.join(sorted(CAMERA_KEYS))})"
        )
    merged = {**defaults, **table}
    keys = DEVICE_KEYS[backend]
    for key in sorted({k for ks in DEVICE_KEYS.values() for k in ks} - set(keys)):
        if key in merged:
            raise UserError(
                f"{_SOURCE}: setting {where}.{key} is not for backend {backend!r} "
                f"(it names a device by {' or '.join(keys)})"
            )
    given = [key for key in keys if merged.get(key) is not None]
    if len(given) != 1:
        raise UserError(f"{_SOURCE}: camera {name!r} needs one of {where}.{keys[0]} or .{keys[1]}")
    for key in given:
        _text(f"{where}.{key}", merged[key])
    if "width" not in merged:
        raise UserError(f"{_SOURCE}: camera {name!r} needs {where}.width")
    width = _positive(f"{where}.width", merged["width"], integer=True)
    offset = merged.get("offset_px", 0)
    if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
        raise _bad(f"{where}.offset_px", offset, "an integer >= 0")
    pixel_format = merged.get("pixel_format", "Mono8")
    if pixel_format not in PIXEL_FORMATS:
        raise _bad(f"{where}.pixel_format", pixel_format, f"one of {', '.join(PIXEL_FORMATS)}")
    exposure = merged.get("exposure_us")
    if exposure is not None:
        exposure = float(_positive(f"{where}.exposure_us", exposure))
    packet_size = merged.get("packet_size")
    if packet_size is not None:
        packet_size = _positive(f"{where}.packet_size", packet_size, integer=True)
        if not 576 <= packet_size <= 16384:
            raise _bad(f"{where}.packet_size", packet_size, "576-16384 bytes")
    return CameraSettings(
        name,
        merged.get("address"),
        merged.get("serial"),
        width,
        offset,
        pixel_format,
        exposure,
        packet_size,
        merged.get("device_id"),
    )


def _producers(value: object) -> tuple[str, ...]:
    """Backend ``gentl``'s producers: the ``cti`` setting, a file or a list of files, else every
    ``.cti`` file in the folders of ``GENICAM_GENTL64_PATH``; ``UserError`` if there is none."""
    if value is None:
        folders = os.environ.get(GENTL_PATH_VARIABLE, "")
        found = tuple(
            str(path)
            for folder in folders.split(os.pathsep)
            if folder
            for path in sorted(Path(folder).glob("*.cti"))
            if path.is_file()
        )
        if not found:
            raise UserError(
                f"{_SOURCE}: backend 'gentl' needs setting cti (a GenTL producer's .cti file) "
                f"or {GENTL_PATH_VARIABLE} naming a folder with one "
                f"({GENTL_PATH_VARIABLE} = {folders!r})"
            )
        return found
    files = [value] if isinstance(value, str) else value
    if not isinstance(files, list) or not files:
        raise _bad("cti", value, "a GenTL producer's .cti file or a list of them")
    for file in files:
        _text("cti", file)
        if not Path(file).is_file():
            raise UserError(f"{_SOURCE}: setting cti = {file!r}: no such file")
    return tuple(files)


def parse_settings(settings: Mapping[str, Any]) -> GigeSettings:
    """Validate the ``gige`` source's settings (module docstring); ``UserError`` if wrong."""
    unknown = sorted(set(settings) - TOP_KEYS)
    if unknown:
        raise UserError(
            f"{_SOURCE}: unknown setting {unknown[0]!r} (known: {', '.join(sorted(TOP_KEYS))})"
        )
    tables = settings.get("cameras")
    if not isinstance(tables, Mapping) or not tables:
        raise _bad("cameras", tables, "a table of the rig's cameras by name")
    backend = settings.get("backend", "aravis")
    if backend not in BACKENDS:
        raise _bad("backend", backend, f"one of {', '.join(BACKENDS)}")
    if backend != "gentl" and "cti" in settings:
        raise UserError(f"{_SOURCE}: setting cti is for backend 'gentl', not {backend!r}")
    cti = _producers(settings.get("cti")) if backend == "gentl" else ()
    defaults = {k: settings[k] for k in SHARED_CAMERA_KEYS if k in settings}
    cameras = tuple(_camera(str(name), table, defaults, backend) for name, table in tables.items())
    for key in ("address", "serial", "device_id"):
        seen: dict[str, str] = {}
        for camera in cameras:
            value = getattr(camera, key)
            if value is not None and value in seen:
                raise UserError(
                    f"{_SOURCE}: cameras {seen[value]!r} and {camera.name!r} share {key} {value!r}"
                )
            if value is not None:
                seen[value] = camera.name
    trigger = settings.get("trigger", "free")
    if trigger not in TRIGGERS:
        raise _bad("trigger", trigger, "free or encoder")
    line_rate = settings.get("line_rate_hz")
    if line_rate is not None:
        line_rate = float(_positive("line_rate_hz", line_rate))
    metres = settings.get("metres_per_line")
    if metres is not None:
        metres = float(_positive("metres_per_line", metres))
    if trigger == "free" and line_rate is None:
        raise UserError(f"{_SOURCE}: trigger 'free' needs line_rate_hz")
    if trigger == "encoder" and metres is None:
        raise UserError(f"{_SOURCE}: trigger 'encoder' needs metres_per_line")
    if trigger == "free" and metres is not None:
        raise UserError(f"{_SOURCE}: metres_per_line is for trigger 'encoder', not 'free'")
    nominal = settings.get("nominal_rate_hz")
    if nominal is not None:
        nominal = float(_positive("nominal_rate_hz", nominal))
    nominal = nominal or line_rate or 1000.0
    direction = settings.get("direction", "increasing")
    if direction not in ("increasing", "decreasing"):
        raise _bad("direction", direction, "increasing or decreasing")
    start = settings.get("start_chainage_m", 0.0)
    if isinstance(start, bool) or not isinstance(start, int | float) or not math.isfinite(start):
        raise _bad("start_chainage_m", start, "a finite number")
    synchronized = settings.get("synchronized_clocks", False)
    if not isinstance(synchronized, bool):
        raise _bad("synchronized_clocks", synchronized, "true or false")
    lag = settings.get("arrival_lag_frames", 1.0)
    if isinstance(lag, bool) or not isinstance(lag, int | float) or not 0 <= lag < math.inf:
        raise _bad("arrival_lag_frames", lag, "a number of frames, 0 or more")
    names = {}
    for key in ("line", "track", "vehicle"):
        value = settings.get(key, "")
        if not isinstance(value, str):
            raise _bad(key, value, "a string")
        names[key] = value
    return GigeSettings(
        cameras=cameras,
        backend=backend,
        cti=cti,
        trigger=trigger,
        line_rate_hz=line_rate,
        trigger_line=_text("trigger_line", settings.get("trigger_line", "Line0")),
        metres_per_line=metres,
        lines_per_frame=_positive(
            "lines_per_frame", settings.get("lines_per_frame", 256), integer=True
        ),
        buffers=_positive("buffers", settings.get("buffers", 32), integer=True),
        timeout_s=float(_positive("timeout_s", settings.get("timeout_s", 2.0))),
        reconnect_interval_s=float(
            _positive("reconnect_interval_s", settings.get("reconnect_interval_s", 1.0))
        ),
        synchronized_clocks=synchronized,
        arrival_lag_frames=float(lag),
        nominal_rate_hz=nominal,
        direction=direction,
        start_chainage_m=float(start),
        **names,
    )
