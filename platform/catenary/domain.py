"""Domain types shared by every source, processor and store (units in the field names).

Frames and units are those of ``FORMATS.md``: roof and track frames in millimetres, positions
along the track in metres, times in seconds.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IntArray, UInt8Array, UInt16Array

DEFAULT_BLOCK_SCANS = 1024
"""Scans per block when a source or reader is not told otherwise."""

ALERT_STATUSES = ("open", "acknowledged", "resolved")
"""An alert's life cycle."""
MAINTENANCE_KINDS = ("wire_replaced", "reinforced", "spliced", "inspected", "adjusted")
"""The work a maintenance action records."""
REPAIR_KINDS = ("wire_replaced", "reinforced", "spliced")
"""Kinds of action that renew the worn profile: they resolve alerts and restart histories."""

CODE_LENGTH = 32
"""Characters of a code in the database: line, track, mast, anchor section, wire type."""
NAME_LENGTH = 200
"""Characters of a name in the database: vehicles, calibrations, people, rules, notifiers."""
PATH_LENGTH = 1024
"""Characters of a file's path in the database."""


@dataclass(frozen=True)
class VehicleGeometry:
    """The car body's geometry for vehicle compensation (FORMATS.md, vehicle TOML)."""

    name: str
    roof_height_mm: float
    sensor_height_mm: float
    sensor_baseline_mm: float


@dataclass(frozen=True)
class VehicleSamples:
    """The three displacement sensors, each ``[K]``, on the scan clock.

    ``fault`` marks samples that must not be trusted (dropped frames, stuck or out-of-range
    sensor); consumers flag the affected scans instead of silently interpolating over them.
    """

    time_s: FloatArray
    left_mm: FloatArray
    right_mm: FloatArray
    lateral_mm: FloatArray
    fault: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        if self.fault.shape != self.time_s.shape:
            object.__setattr__(self, "fault", np.zeros(self.time_s.shape, dtype=bool))


@dataclass(frozen=True)
class CameraLines:
    """One camera's lines for a block of scans: ``lines`` is ``[n, W]`` uint8 or uint16.

    ``offset_px``: line pixel ``i`` is pixel ``offset_px + i`` of the camera's sensor (a
    region of interest; 0: the lines start at the sensor's first pixel). ``valid``: bool
    ``[n]``, false where the camera delivered no line for the scan (a lost or incomplete
    buffer: that camera did not see the scan, and the line's pixels are meaningless, e.g.
    zeros); None: every line is valid (FORMATS.md ``/cameras/{name}/valid``).
    """

    lines: UInt8Array | UInt16Array
    bit_depth: int
    offset_px: int = 0
    valid: BoolArray | None = None


@dataclass(frozen=True)
class EncoderReadings:
    """The wheel encoder's raw readings, each ``[E]``: ``time_s`` on the scan clock
    (non-decreasing), ``position_m`` the distance it counted [m] (from any origin; faulty
    readings left out). FORMATS.md ``/encoder/*``."""

    time_s: FloatArray
    position_m: FloatArray


@dataclass(frozen=True)
class ScanBlock:
    """A block of ``n`` consecutive scans of a run, every camera triggered together.

    ``first_scan`` is the index of the block's first scan in the run; ``position_m`` and
    ``time_s`` are ``[n]``; ``vehicle`` holds the sensor values interpolated to the scan times
    (each field ``[n]``; ``fault`` true where a sample used was faulty or missing).
    """

    first_scan: int
    position_m: FloatArray
    time_s: FloatArray
    cameras: dict[str, CameraLines]
    vehicle: VehicleSamples

    @property
    def scans(self) -> int:
        return int(self.position_m.shape[0])


@dataclass(frozen=True)
class RunHeader:
    """A recorded run's root attributes (FORMATS.md) and its shape.

    ``camera_pixels`` is each camera's line width ``W``; ``camera_offset_px`` holds the
    region of interest's first sensor pixel of the cameras that declare one (attribute
    ``offset_px``): the others' lines hold the whole sensor.
    """

    line: str
    track: str
    vehicle: str
    direction: str  # "increasing" or "decreasing" chainage
    start_chainage_m: float
    started_at: str  # ISO 8601 UTC
    scan_rate_hz: float
    scans: int
    camera_pixels: dict[str, int]
    camera_bit_depth: dict[str, int]
    camera_offset_px: dict[str, int] = field(default_factory=dict)


@dataclass(frozen=True)
class WireObservations:
    """Contact wire observations from a processor, one row per scan and wire, each ``[m]``.

    ``scan`` is the scan's index in the run, ``wire`` the wire number (stable along the run:
    a wire keeps its number from where it enters the view to where it leaves). Positions are
    in the roof frame [mm], ``z`` the contact point (the bottom of the worn face).
    ``wear_width_mm`` is the worn face's width in the scanning plane, before the stagger-angle
    correction; ``cameras`` how many cameras confirmed the point; ``reprojection_rms_px`` the
    triangulation's residual. ``selection_uncertain`` is true where the processor could not
    decide that the point is the contact wire (it may be a messenger, a dropper or an arm):
    such rows are stored, flagged, and left out of span figures and alerts; all false when not
    given.
    """

    scan: IntArray
    wire: IntArray
    x_roof_mm: FloatArray
    z_roof_mm: FloatArray
    wear_width_mm: FloatArray
    cameras: IntArray
    reprojection_rms_px: FloatArray
    selection_uncertain: BoolArray = field(default_factory=lambda: np.zeros(0, dtype=bool))

    def __post_init__(self) -> None:
        flag = np.asarray(self.selection_uncertain, dtype=bool)
        if flag.shape == (0,):  # not given: every row is the contact wire
            flag = np.zeros(self.scan.shape, dtype=bool)
        if flag.shape != self.scan.shape:
            raise ValueError(
                f"selection_uncertain {flag.shape} does not match the {self.scan.shape} rows"
            )
        object.__setattr__(self, "selection_uncertain", flag)

    @property
    def rows(self) -> int:
        return int(self.scan.shape[0])


OPTIONAL_MAST_NUMBERS = ("design_height_mm", "line_speed_kmh", "latitude", "longitude")
"""The register's optional numeric columns beside ``design_stagger_mm`` (``TrackRegister``)."""


@dataclass(frozen=True)
class TrackRegister:
    """The masts of one line and track, sorted by chainage (each ``(k,)``)."""

    line: str
    track: str
    mast: tuple[str, ...]
    chainage_m: FloatArray
    wire_type: tuple[str, ...]
    design_stagger_mm: FloatArray  # NaN where not given
    anchor_section: tuple[str | None, ...] | None = None  # None: the register has no such column
    # the optional numeric columns (FORMATS.md), NaN where a mast gives none; None: the
    # register has no such column
    design_height_mm: FloatArray | None = None
    line_speed_kmh: FloatArray | None = None
    latitude: FloatArray | None = None
    longitude: FloatArray | None = None

    @property
    def masts(self) -> int:
        return len(self.mast)

    def span_name(self, span: int) -> tuple[str, str]:
        """The masts at the start and end of span ``span`` (from mast ``span`` to the next)."""
        return self.mast[span], self.mast[span + 1]
