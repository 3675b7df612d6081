"""The line-scan stereovision processor: scan blocks + rig calibration -> contact wires.

The paper's processing module (section 3.3, figure 11, steps 2-3, and section 3.2, steps
1-5), streaming over blocks of scans:

1. profile features of every camera's lines (:mod:`.features`);
2. stereo matching across the cameras and triangulation of the confirmed points
   (:mod:`.matching`), with the worn face's width in mm from every confirming camera; a
   point is left unverified where a camera that did not confirm it shows only sky in its
   line there (a ghost: :mod:`.matching.evidence`), so that it can continue a tracked
   wire, never start one;
3. wire selection along the run (:mod:`.tracking`): messengers out by height, droppers and
   steady arms out by continuity, one wire number per contact wire.

The output is :class:`catenary.domain.WireObservations` in the roof frame: the vehicle
compensation, the stagger-angle correction (:mod:`catenary.measurement.wear`) and the residual
thickness (the run's wire type) follow in the pipeline. ``cameras`` is the number of cameras that
confirmed the point (a merged silhouette's support included): 3 or more, or 2 where a
tracked wire was seen, with its worn face, by two cameras only. ``wear_width_mm`` is the worn
face's width in the scanning plane from the cameras that agree on it (0.0: no face seen, a
new wire or one narrower than the features resolve; NaN: faces seen but not agreed on).
Tracking holds back the points of the last metres until they are decided:
:meth:`LineScanProcessor.finish` returns them at the end of the run. Steps 1 and 2 depend on
the block alone: they are the processor's ``stage`` (:class:`LineScanStage`, picklable), which
``catenary process --workers N`` runs for several blocks at once in worker processes, and step
3 its ``process_staged``, in run order.

``create(rig_path, settings)`` is the factory of the ``Processor`` registration. Settings
(all optional):

=========================  ====================================================================
``min_cameras``            cameras that must confirm a point (default: 3 with three or more)
``max_candidates``         candidates kept per scan and camera (24)
``feature_sigma_px``       features' centre uncertainty for the confirmation window (0.15)
``confirm_sigmas``         confirmation window in standard deviations (4)
``floor_px``               narrowest confirmation window (0.6)
``wire_width_mm``          [min, max] contact wire widths the features look for ([10.6, 14.8]);
                           half their mean is the radius of a wire whose face no two cameras
                           saw (a new wire: its silhouettes' middle is lowered to its bottom by
                           it) where its dark silhouettes do not measure it (at night, behind
                           the filter) and the run's wire types are not known: ``catenary
                           process`` tells them (:meth:`LineScanProcessor.expect_wire_types`)
``min_track_m``            shortest track taken for a wire (``tracking.MIN_TRACK_M``)
``max_gap_m``              longest gap a track bridges (1.0)
``messenger_gap_mm``       height above the lowest contact wire of a messenger (200)
``max_height_mm``          highest a contact wire runs above the roof (3000)
``outlines``               find a faceless wire's outline on one side only (true: features
                           module, ``FeatureConfig.outlines``)
``width_tolerance_mm``     cameras further than this from the median face width are left out
``table_tolerance``        largest relative difference between the camera model's and the
                           look-up table's resolution accepted before a warning (0.03)
=========================  ====================================================================
"""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from catenary.arrays import BoolArray, FloatArray, IntArray
from catenary.domain import RunHeader, ScanBlock, WireObservations
from catenary.errors import UserError
from catenary.measurement.vehicle import roll_rad
from catenary.wiretype import WireType
from catenary_linescan.calibration import ResolutionTable
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.rig import Rig, read_rig

from .features import FeatureConfig, extract_features
from .matching import (
    CONTACT_WIRE_WIDTH_MM,
    MatchConfig,
    Matches,
    camera_sigmas_px,
    face_widths_mm,
    lit_chord_mm,
    match,
    pad_candidates,
)
from .matching.evidence import unseen_in_lines
from .tracking import UNCERTAIN_COLUMN, TrackedPoints, TrackingConfig, WireTracker

__all__ = [
    "LineScanProcessor",
    "LineScanStage",
    "ProcessorConfig",
    "StagedBlock",
    "create",
    "empty_observations",
    "fit_problem",
]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ProcessorConfig:
    """Settings of :class:`LineScanProcessor` (see the module docstring for the keys).

    ``features`` None derives the feature settings from the rig: the contact wire widths
    ``wire_width_mm`` at the finest and coarsest resolution of the rig's look-up tables.
    ``run_wire_widths_mm`` are the widths (B) of the wire types the run may hold, where they
    are known (not a setting: :meth:`LineScanProcessor.expect_wire_types`).
    """

    features: FeatureConfig | None = None
    matching: MatchConfig = field(default_factory=MatchConfig)
    tracking: TrackingConfig = field(default_factory=TrackingConfig)
    wire_width_mm: tuple[float, float] = CONTACT_WIRE_WIDTH_MM
    outlines: bool = True
    width_tolerance_mm: float = 0.25
    table_tolerance: float = 0.03
    run_wire_widths_mm: tuple[float, ...] = ()

    @property
    def wire_radius_mm(self) -> float:
        """Radius assumed for a wire whose face no two cameras saw [mm]: half the mean width
        of the run's wire types, else of ``wire_width_mm``."""
        widths = self.run_wire_widths_mm or self.wire_width_mm
        return 0.5 * sum(widths) / len(widths)

    @classmethod
    def from_settings(cls, settings: Mapping[str, Any]) -> ProcessorConfig:
        """Parse the processor settings (module docstring); ``UserError`` names a bad key."""
        matching_keys = {
            "min_cameras": int,
            "max_candidates": int,
            "feature_sigma_px": float,
            "confirm_sigmas": float,
            "floor_px": float,
        }
        tracking_keys = {
            "min_track_m": float,
            "max_gap_m": float,
            "messenger_gap_mm": float,
            "max_height_mm": float,
        }
        own_keys = {"width_tolerance_mm": float, "table_tolerance": float}
        known = {
            **matching_keys,
            **tracking_keys,
            **own_keys,
            "wire_width_mm": list,
            "outlines": bool,
        }
        unknown = sorted(set(settings) - set(known))
        if unknown:
            raise UserError(
                f"unknown line-scan processor setting {unknown[0]!r} (known: {', '.join(known)})"
            )
        values: dict[str, Any] = {}
        for key, value in settings.items():
            kind = known[key]
            if kind is bool:
                if not isinstance(value, bool):
                    raise UserError(f"processor setting {key} = {value!r}: expected true or false")
                values[key] = value
                continue
            if kind is list:
                try:
                    low, high = (float(v) for v in value)
                except (TypeError, ValueError):
                    raise UserError(
                        f"processor setting {key} = {value!r}: expected [min, max] in mm"
                    ) from None
                if not 0.0 < low <= high:
                    raise UserError(f"processor setting {key} = {value!r}: need 0 < min <= max")
                values[key] = (low, high)
                continue
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise UserError(f"processor setting {key} = {value!r}: expected a number")
            if kind is int and value != int(value):
                raise UserError(f"processor setting {key} = {value!r}: expected an integer")
            number = kind(value)
            if not math.isfinite(number) or number <= 0:
                raise UserError(f"processor setting {key} = {value!r}: expected a positive value")
            values[key] = number
        matching = replace(MatchConfig(), **{k: v for k, v in values.items() if k in matching_keys})
        tracking = replace(
            TrackingConfig(), **{k: v for k, v in values.items() if k in tracking_keys}
        )
        own = {
            k: v for k, v in values.items() if k in own_keys or k in ("wire_width_mm", "outlines")
        }
        return cls(matching=matching, tracking=tracking, **own)


def empty_observations() -> WireObservations:
    """A :class:`WireObservations` with no rows."""
    return WireObservations(
        scan=np.zeros(0, np.int64),
        wire=np.zeros(0, np.int64),
        x_roof_mm=np.zeros(0),
        z_roof_mm=np.zeros(0),
        wear_width_mm=np.zeros(0),
        cameras=np.zeros(0, np.int64),
        reprojection_rms_px=np.zeros(0),
    )


def _observations(points: TrackedPoints) -> WireObservations:
    """The tracker's released points as observations; ``selection_uncertain`` from the
    tracker's column of that name where it gives one, else all false; the width is the
    tracker's ``face_mm`` (none at a turnout's crossing)."""
    columns = points.columns
    uncertain = columns.get(UNCERTAIN_COLUMN)
    return WireObservations(
        scan=points.scan,
        wire=points.wire,
        x_roof_mm=points.x_mm,
        z_roof_mm=points.z_mm,
        wear_width_mm=points.face_mm,
        cameras=np.asarray(columns["cameras"], dtype=np.int64),
        reprojection_rms_px=np.asarray(columns["reprojection_rms_px"], dtype=np.float64),
        selection_uncertain=np.zeros(points.rows, dtype=bool)
        if uncertain is None
        else np.asarray(uncertain, dtype=bool),
    )


class LineScanProcessor:
    """The paper's processor over any rig (the ``BlockProcessor`` protocol).

    Parameters
    ----------
    rig : Rig
        The calibrated rig: cameras (two at least), their reprojection RMS and look-up
        tables, and the vehicle geometry (the sensor baseline, for the body's roll).
    config : ProcessorConfig, optional

    Notes
    -----
    Blocks must come in run order (``first_scan`` increasing), each holding every camera of
    the rig (others are ignored). A camera's lines may be a region of interest of its sensor
    (``CameraLines.offset_px``); :meth:`check_run` refuses a run whose lines do not fit. Each
    :meth:`process` returns the observations decided so far (possibly of earlier blocks'
    scans, possibly none); :meth:`finish` returns the rest.
    """

    def __init__(self, rig: Rig, config: ProcessorConfig | None = None) -> None:
        self.rig = rig
        self._configure(config or ProcessorConfig())

    def expect_wire_types(self, wire_types: Sequence[WireType]) -> None:
        """Take the radius of a wire whose face no two cameras saw from the widths of the
        wire types the run may hold (``WireTypesUser``; before the first block)."""
        if self._next_scan:
            raise ValueError("the wire types come before the first block")
        widths = tuple(sorted({wire.width_mm for wire in wire_types}))
        self._configure(replace(self.config, run_wire_widths_mm=widths))

    def _configure(self, config: ProcessorConfig) -> None:
        """Set up the settings, the stage and the tracking for ``config`` (no block yet)."""
        rig = self.rig
        self.config = config
        self.names = list(rig.cameras)
        if len(self.names) < 2:
            raise UserError(f"rig {rig.vehicle.name!r} has {len(self.names)} camera; need two")
        self.cameras = [rig.cameras[name].camera for name in self.names]
        self.tables = [rig.cameras[name].resolution for name in self.names]
        self.sigma_px = camera_sigmas_px(
            [rig.cameras[name].reprojection_rms_px for name in self.names],
            self.config.matching.feature_sigma_px,
        )
        self.features = self.config.features or self._feature_config()
        self.matching = replace(
            self.config.matching,
            max_wire_width_mm=self.config.wire_width_mm[1],
            min_wire_width_mm=self.config.wire_width_mm[0],
            wire_radius_mm=self.config.wire_radius_mm,
        )
        self._stage = LineScanStage(
            rig_name=rig.vehicle.name,
            names=tuple(self.names),
            cameras=tuple(self.cameras),
            tables=tuple(self.tables),
            pixels=tuple(camera.pixels for camera in self.cameras),
            sigma_px=self.sigma_px,
            features=self.features,
            matching=self.matching,
            baseline_mm=rig.vehicle.sensor_baseline_mm,
            wire_radius_mm=self.config.wire_radius_mm,
            width_tolerance_mm=self.config.width_tolerance_mm,
            max_width_mm=self.config.wire_width_mm[1],
        )
        self.tracker = WireTracker(self.config.tracking)
        self._next_scan = 0
        self._ratio_sum = np.zeros(len(self.names))
        self._ratio_count = np.zeros(len(self.names), dtype=np.int64)
        self._warned = np.zeros(len(self.names), dtype=bool)

    def _feature_config(self) -> FeatureConfig:
        fine = min(float(np.min(t.mm_per_px)) for t in self.tables)
        coarse = max(float(np.max(t.mm_per_px)) for t in self.tables)
        return FeatureConfig.from_resolution(
            self.config.wire_width_mm, (fine, coarse), outlines=self.config.outlines
        )

    @property
    def table_check(self) -> dict[str, float]:
        """Per camera, the mean ratio of the camera model's face widths to the look-up
        table's over every face measured so far (1.0: they agree; NaN: no face yet)."""
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = self._ratio_sum / self._ratio_count
        return dict(zip(self.names, mean.tolist(), strict=True))

    def check_run(self, header: RunHeader) -> None:
        """Refuse a run that does not fit the rig, before any scan (``RunChecker``): a rig
        camera it lacks, or lines that are not the camera's sensor (``fit_problem``). A
        camera of the run that the rig lacks (an overview camera) is named in one warning
        and ignored."""
        missing = [name for name in self.names if name not in header.camera_pixels]
        if missing:
            raise UserError(
                f"the run has no camera {missing[0]!r} of rig {self.rig.vehicle.name!r} "
                f"(cameras: {', '.join(header.camera_pixels)})"
            )
        for name in self.names:
            problem = fit_problem(
                self.rig.vehicle.name,
                name,
                self.rig.cameras[name].camera.pixels,
                header.camera_pixels[name],
                header.camera_offset_px.get(name),
            )
            if problem is not None:
                raise UserError(problem)
        for name in sorted(set(header.camera_pixels) - set(self.names)):
            log.warning(
                "warning: camera %r of the run is not in rig %r: ignored",
                name,
                self.rig.vehicle.name,
            )

    def image_columns(self, x_roof_mm: FloatArray, z_roof_mm: FloatArray) -> dict[str, FloatArray]:
        """Each camera's sensor pixel of roof-frame points (``ImageLocator``), ``(k,)``;
        NaN where the camera cannot see one."""
        columns = {}
        for name, camera in zip(self.names, self.cameras, strict=True):
            u = np.asarray(camera.project(x_roof_mm, z_roof_mm), dtype=np.float64)
            columns[name] = np.where(camera.in_view(x_roof_mm, z_roof_mm), u, np.nan)
        return columns

    @property
    def stage(self) -> LineScanStage:
        """The stateless part of :meth:`process` (``StagedProcessor``): picklable."""
        return self._stage

    def process(self, block: ScanBlock) -> WireObservations:
        """Process one block of scans; return the observations now decided."""
        return self.process_staged(block, self._stage(block))

    def process_staged(self, block: ScanBlock, staged: StagedBlock | None) -> WireObservations:
        """The stateful rest of :meth:`process` (``StagedProcessor``), in run order: the
        model-versus-table check and tracking of ``staged = stage(block)``."""
        if block.first_scan < self._next_scan:
            raise ValueError(
                f"block at scan {block.first_scan} after scans up to {self._next_scan - 1}"
            )
        n = block.scans
        if staged is None:
            return empty_observations()
        self._next_scan = block.first_scan + n
        self._check_tables(staged.table_ratio)
        released = self.tracker.push(
            block.first_scan + staged.scan,
            block.position_m[staged.scan],
            staged.x_mm,
            staged.z_mm,
            {
                "cameras": staged.cameras,
                "reprojection_rms_px": staged.reprojection_rms_px,
            },
            verified=staged.verified,
            face_mm=staged.wear_width_mm,
            last_scan=block.first_scan + n - 1,
            last_position_m=float(block.position_m[-1]),
        )
        return _observations(released)

    def finish(self) -> WireObservations:
        """The observations tracking still held back (call once, after the last block)."""
        return _observations(self.tracker.finish())

    def _check_tables(self, ratio: np.ndarray[Any, Any]) -> None:
        """Accumulate the model-versus-table cross-check; warn once per camera when off."""
        seen = np.isfinite(ratio)
        self._ratio_sum += np.where(seen, ratio, 0.0).sum(axis=0)
        self._ratio_count += seen.sum(axis=0)
        with np.errstate(invalid="ignore", divide="ignore"):
            mean = self._ratio_sum / self._ratio_count
        off = (self._ratio_count >= 100) & (np.abs(mean - 1.0) > self.config.table_tolerance)
        for c in np.flatnonzero(off & ~self._warned):
            log.warning(
                "camera %r: face widths from the camera model differ from the look-up "
                "table's by %+.1f %% (tolerance %.1f %%): check the rig calibration",
                self.names[c],
                100.0 * (mean[c] - 1.0),
                100.0 * self.config.table_tolerance,
            )
            self._warned[c] = True


def fit_problem(
    rig_name: str, name: str, pixels: int, width: int, offset_px: int | None
) -> str | None:
    """Why camera ``name``'s lines of ``width`` pixels, starting at sensor pixel
    ``offset_px`` (None: not declared, the lines must hold the whole sensor), do not fit
    the ``pixels`` rig ``rig_name`` calibrated; None when they fit."""
    if offset_px is None:
        if width == pixels:
            return None
        return (
            f"camera {name!r}: lines of {width} pixels, but rig {rig_name!r} "
            f"calibrated it with {pixels} (a region of interest declares offset_px)"
        )
    if offset_px + width <= pixels:
        return None
    return (
        f"camera {name!r}: offset_px {offset_px} + {width} pixels = {offset_px + width}, "
        f"beyond the {pixels} pixels rig {rig_name!r} calibrated"
    )


@dataclass(frozen=True)
class StagedBlock:
    """What :class:`LineScanStage` found in a block: ``m`` points, each ``(m,)``, and the
    model-versus-table resolution ratio of every face measured, ``(k, C)``.

    ``scan`` is the index within the block; the other columns are those tracking takes."""

    scan: IntArray
    x_mm: FloatArray
    z_mm: FloatArray
    wear_width_mm: FloatArray
    cameras: IntArray
    reprojection_rms_px: FloatArray
    verified: BoolArray
    table_ratio: FloatArray


@dataclass(frozen=True)
class LineScanStage:
    """The stateless part of :class:`LineScanProcessor` (its ``stage``): features,
    matching, contact points and face widths of one block, from the rig alone; picklable,
    so that blocks may be staged in worker processes. A line its camera did not deliver
    (``CameraLines.valid`` false) gives no candidate: that camera did not see the scan, as
    a blinded one, and the others match without it (two at least)."""

    rig_name: str
    names: tuple[str, ...]
    cameras: tuple[LineScanCamera, ...]
    tables: tuple[ResolutionTable, ...]
    pixels: tuple[int, ...]
    sigma_px: FloatArray
    features: FeatureConfig
    matching: MatchConfig
    baseline_mm: float
    wire_radius_mm: float
    width_tolerance_mm: float
    max_width_mm: float

    def __call__(self, block: ScanBlock) -> StagedBlock | None:
        """Stage ``block`` (None: it has no scan); a ``UserError`` for a block that lacks a
        camera of the rig or whose lines do not fit it."""
        missing = [name for name in self.names if name not in block.cameras]
        if missing:
            raise UserError(
                f"scan block at scan {block.first_scan} has no camera {missing[0]!r} "
                f"of rig {self.rig_name!r} (cameras: {', '.join(block.cameras)})"
            )
        for name, pixels in zip(self.names, self.pixels, strict=True):
            # within the sensor (the whole-sensor check: check_run)
            lines = block.cameras[name]
            problem = fit_problem(
                self.rig_name, name, pixels, lines.lines.shape[1], lines.offset_px
            )
            if problem is not None:
                raise UserError(problem)
        n = block.scans
        if n == 0:
            return None
        features = []
        for name in self.names:
            lines = block.cameras[name]
            if lines.lines.shape[0] != n:
                raise UserError(
                    f"camera {name!r} has {lines.lines.shape[0]} lines in a block of {n} scans"
                )
            found = extract_features(lines.lines, lines.bit_depth, config=self.features)
            if lines.valid is not None:  # no line delivered: the camera did not see the scan
                if lines.valid.shape != (n,):
                    raise UserError(
                        f"camera {name!r} has {lines.valid.shape} valid flags in a block of "
                        f"{n} scans"
                    )
                found = found.select(lines.valid[found.scan])
            features.append(found)
        offsets = [block.cameras[name].offset_px for name in self.names]
        candidates = pad_candidates(features, n, self.matching.max_candidates, offsets)
        cameras = list(self.cameras)
        matches = match(cameras, candidates, self.sigma_px, self.matching)
        full = [float((1 << block.cameras[name].bit_depth) - 1) for name in self.names]
        unseen = unseen_in_lines(
            cameras,
            [block.cameras[name].lines for name in self.names],
            offsets,
            full,
            candidates,
            matches,
            self.max_width_mm,
            self.features,
        )
        matches = replace(matches, verified=matches.verified & ~unseen)
        vehicle = block.vehicle
        roll = roll_rad(vehicle.left_mm, vehicle.right_mm, self.baseline_mm)
        roll = np.where(np.isfinite(roll), roll, 0.0)
        if roll.shape != (n,):
            roll = np.zeros(n)
        chord = lit_chord_mm(cameras, candidates, matches, roll)
        matches = contact_from_axis(matches, roll, self.wire_radius_mm, chord)
        widths = face_widths_mm(
            cameras,
            list(self.tables),
            candidates,
            matches,
            roll,
            tolerance_mm=self.width_tolerance_mm,
            max_width_mm=self.max_width_mm,
        )
        valid = np.isfinite(matches.x_mm) & np.isfinite(matches.z_mm)
        return StagedBlock(
            scan=matches.scan[valid],
            x_mm=matches.x_mm[valid],
            z_mm=matches.z_mm[valid],
            wear_width_mm=widths.width_mm[valid],
            cameras=matches.cameras[valid],
            reprojection_rms_px=matches.reprojection_rms_px[valid],
            verified=matches.verified[valid],
            table_ratio=widths.table_ratio,
        )


def contact_from_axis(
    matches: Matches, roll_rad: np.ndarray, radius_mm: float, chord_mm: FloatArray
) -> Matches:
    """The contact point of the matches located by their silhouettes (no face:
    ``from_face`` false): a round wire's lowest point.

    The middles of the silhouettes triangulate to the middle of the chord between the
    silhouette's ends. When the whole wire shows (or ``chord_mm`` is NaN) that is the axis,
    ``radius_mm`` above the lowest point (the radius measured at the point where it was:
    ``Matches.radius_mm``); when only its lit bottom shows, a chord of
    ``chord_mm`` lies ``r - sqrt(r² - (chord/2)²)`` above it. The point is lowered by that
    along the track frame's vertical, which the body's roll ``roll_rad`` (per scan of the
    block, shape (n,), positive: left side up) tilts to ``(-sin φ, cos φ)`` in the roof
    frame."""
    radius = np.where(np.isfinite(matches.radius_mm), matches.radius_mm, radius_mm)
    half = np.minimum(0.5 * np.where(np.isnan(chord_mm), 2.0 * radius, chord_mm), radius)
    drop = np.where(matches.from_face, 0.0, radius - np.sqrt(radius**2 - half**2))
    phi = roll_rad[matches.scan]
    return replace(
        matches,
        x_mm=matches.x_mm + drop * np.sin(phi),
        z_mm=matches.z_mm - drop * np.cos(phi),
    )


def create(rig_path: Path, settings: Mapping[str, Any]) -> LineScanProcessor:
    """The ``Processor`` registration's factory: read the rig, parse the settings."""
    rig = read_rig(rig_path)
    return LineScanProcessor(rig, ProcessorConfig.from_settings(settings))
