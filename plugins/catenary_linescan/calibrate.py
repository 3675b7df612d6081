"""``catenary calibrate``: a rig calibration from calibration captures or a point list.

From captures (FORMATS.md HDF5): every camera's targets are measured and assigned in every
line (without a nominal rig, the assignment is bootstrapped from the detections:
``captures.bootstrap_camera``), and each camera's matrix is estimated from the target centres
(normalised DLT, then non-linear least squares with outlier rejection).

The resolution look-up table (paper section 3.2) is kept on the captures' grid of target
positions and bar heights, and interpolated bilinearly. Its values come from the calibrated
camera model (``1 / |du/dx|``), which the target centres of every height and position
determine together; the paper's table measured node by node (flat width / face width in
pixels) is built too, stored beside it as ``measured_resolution`` and compared: the face
widths carry their edges' noise and bias (on the demo captures 0.05-0.08 px wider than the
true faces, 0.4-0.6 % in resolution, up to 5 % at single nodes), which the model does not.
From a CSV point list (``camera,x_mm,z_mm,u_px``) there are no face widths, so no measured
table, and ``--pixels`` gives the line width.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import click
import numpy as np

from catenary.domain import VehicleGeometry
from catenary.errors import UserError
from catenary.measurement.vehicle import load_vehicle_geometry
from catenary_linescan.calibration import (
    CameraCalibration,
    ResolutionTable,
    build_resolution_table,
    calibrate_camera,
    resolution_table_from_camera,
)
from catenary_linescan.camera import LineScanCamera
from catenary_linescan.captures import measure_capture, read_capture, read_points_csv
from catenary_linescan.rig import (
    DEFAULT_TABLE_X_MM,
    DEFAULT_TABLE_Z_MM,
    Rig,
    RigCamera,
    read_rig,
    write_rig,
)


@dataclass(frozen=True)
class CameraReport:
    """One camera's calibration, its table, and the measured table's deviation from it."""

    calibration: CameraCalibration
    table: ResolutionTable
    measured: ResolutionTable | None = None

    def measured_deviation(self) -> tuple[float, float]:
        """Mean and largest |measured / model - 1| over the measured nodes [-] (NaN: none)."""
        if self.measured is None:
            return math.nan, math.nan
        seen = ~self.measured.filled
        ratio = self.measured.mm_per_px[seen] / self.table.mm_per_px[seen] - 1.0
        if ratio.size == 0:
            return math.nan, math.nan
        return float(np.mean(ratio)), float(np.max(np.abs(ratio)))


def calibrate_from_captures(
    path: Path,
    *,
    distortion: bool | None,
    approximate: Mapping[str, LineScanCamera] | None,
) -> list[CameraReport]:
    """Calibrate every camera of a capture file (``approximate``: cameras to assign targets)."""
    capture = read_capture(path)
    measured = measure_capture(capture, approximate)
    reports = []
    for name, lines in capture.cameras.items():
        targets = measured[name]
        x, z, u = targets.points(capture)
        calibration = calibrate_camera(name, lines.lines.shape[1], x, z, u, distortion=distortion)
        table = build_resolution_table(
            capture.target_x_mm,
            capture.heights_mm,
            targets.width_px,
            capture.flat_width_mm,
            camera=name,
        )
        model = resolution_table_from_camera(calibration.camera, table.x_mm, table.z_mm)
        reports.append(CameraReport(calibration, model, table))
    return reports


def calibrate_from_points(
    path: Path, *, pixels: int | None, distortion: bool | None
) -> list[CameraReport]:
    """Calibrate every camera of a CSV point list; tables come from the camera model."""
    if pixels is None:
        raise UserError(f"{path}: a point list does not give the line width: pass --pixels N")
    points = read_points_csv(path)
    reports = []
    for name in points.cameras:
        x, z, u = points.of_camera(name)
        calibration = calibrate_camera(name, pixels, x, z, u, distortion=distortion)
        table = resolution_table_from_camera(
            calibration.camera, DEFAULT_TABLE_X_MM, DEFAULT_TABLE_Z_MM
        )
        reports.append(CameraReport(calibration, table))
    return reports


def rig_from_reports(
    vehicle: VehicleGeometry, reports: list[CameraReport], *, created_at: str = "", source: str = ""
) -> Rig:
    """The calibrated rig: each camera with its table, figures and measured table."""
    return Rig(
        vehicle=vehicle,
        cameras={
            r.calibration.camera.name: RigCamera(
                camera=r.calibration.camera,
                resolution=r.table,
                reprojection_rms_px=r.calibration.rms_px,
                reprojection_max_px=r.calibration.max_px,
                measured_resolution=r.measured,
            )
            for r in reports
        },
        created_at=created_at,
        source=source,
    )


def _print_reports(reports: list[CameraReport]) -> None:
    click.echo(
        f"{'camera':<10} {'points':>7} {'rejected':>8} {'rms px':>7} {'max px':>7} "
        f"{'k1':>8}  {'table mm/px':>13}  {'measured table vs model':>23}"
    )
    for report in reports:
        c = report.calibration
        values = report.table.mm_per_px
        mean, worst = report.measured_deviation()
        versus = (
            "no face widths"
            if math.isnan(mean)
            else f"mean {100 * mean:+.2f}% max {100 * worst:.2f}%"
        )
        click.echo(
            f"{c.camera.name:<10} {c.points_used:7d} {c.points_rejected:8d} {c.rms_px:7.3f} "
            f"{c.max_px:7.3f} {c.camera.k1:8.4f}  {values.min():6.4f}-{values.max():6.4f}  "
            f"{versus:>23}"
        )


def calibrate_rig(
    captures: Path,
    vehicle_path: Path,
    output: Path,
    distortion: str,
    approximate_path: Path | None,
    pixels: int | None,
) -> None:
    """Calibrate a rig from CAPTURES (.h5 calibration captures or a .csv point list)."""
    vehicle = load_vehicle_geometry(vehicle_path)
    estimate = {"auto": None, "on": True, "off": False}[distortion]
    if captures.suffix.lower() == ".csv":
        reports = calibrate_from_points(captures, pixels=pixels, distortion=estimate)
    else:
        approximate = None
        if approximate_path is not None:
            approximate = {n: c.camera for n, c in read_rig(approximate_path).cameras.items()}
        reports = calibrate_from_captures(captures, distortion=estimate, approximate=approximate)
    if len(reports) < 2:
        raise UserError(f"{captures}: holds {len(reports)} camera(s); a rig needs at least two")
    rig = rig_from_reports(
        vehicle,
        reports,
        created_at=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        source=captures.name,
    )
    write_rig(output, rig)
    _print_reports(reports)
    worst = max(r.calibration.rms_px for r in reports)
    click.echo(f"rig calibration written to {output} (worst reprojection RMS {worst:.3f} px)")
