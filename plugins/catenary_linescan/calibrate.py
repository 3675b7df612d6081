"""``catenary calibrate``: a rig calibration from calibration captures or a point list.

From captures (FORMATS.md HDF5): every camera's targets are measured and assigned in every
line, each camera's matrix is estimated from the target centres (normalised DLT, then
non-linear least squares with outlier rejection), and the resolution look-up table is built
from the flat faces' widths. From a CSV point list (``camera,x_mm,z_mm,u_px``) there are no
face widths: the table is derived from the calibrated matrix instead, and ``--pixels`` gives
the line width.
"""

from __future__ import annotations

from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path

import click
import numpy as np

from catenary.errors import UserError
from catenary.vehicle import load_vehicle_geometry
from catenary_linescan.calibration import (
    CameraCalibration,
    ResolutionTable,
    build_resolution_table,
    calibrate_camera,
    resolution_table_from_camera,
)
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
    """What ``calibrate`` prints per camera."""

    calibration: CameraCalibration
    table: ResolutionTable
    model_deviation: float  # largest |table / camera model - 1| over the table's nodes [-]


def _report(calibration: CameraCalibration, table: ResolutionTable) -> CameraReport:
    model = calibration.camera.resolution_mm_per_px(table.x_mm[np.newaxis, :], table.z_mm[:, None])
    deviation = float(np.max(np.abs(table.mm_per_px / model - 1.0)))
    return CameraReport(calibration, table, deviation)


def calibrate_from_captures(
    path: Path, *, distortion: bool | None, approximate: Rig | None
) -> list[CameraReport]:
    """Calibrate every camera of a capture file."""
    capture = read_capture(path)
    cameras = None if approximate is None else {n: c.camera for n, c in approximate.cameras.items()}
    measured = measure_capture(capture, cameras)
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
        reports.append(_report(calibration, table))
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
        reports.append(_report(calibration, table))
    return reports


def _print_reports(reports: list[CameraReport]) -> None:
    click.echo(
        f"{'camera':<10} {'points':>7} {'rejected':>8} {'rms px':>7} {'max px':>7} "
        f"{'k1':>8}  {'table mm/px':>13} {'filled':>6} {'vs model':>8}"
    )
    for report in reports:
        c = report.calibration
        values = report.table.mm_per_px
        click.echo(
            f"{c.camera.name:<10} {c.points_used:7d} {c.points_rejected:8d} {c.rms_px:7.3f} "
            f"{c.max_px:7.3f} {c.camera.k1:8.4f}  {values.min():6.4f}-{values.max():6.4f} "
            f"{int(report.table.filled.sum()):6d} {100 * report.model_deviation:7.2f}%"
        )


@click.command("calibrate")
@click.argument("captures", type=click.Path(path_type=Path, dir_okay=False, exists=True))
@click.option(
    "--vehicle",
    "vehicle_path",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="Vehicle geometry TOML (FORMATS.md).",
)
@click.option(
    "-o",
    "--output",
    required=True,
    type=click.Path(path_type=Path, dir_okay=False),
    help="Rig calibration TOML to write.",
)
@click.option(
    "--distortion",
    type=click.Choice(["auto", "on", "off"]),
    default="auto",
    show_default=True,
    help="Estimate the radial lens term when the data support it, always, or never.",
)
@click.option(
    "--approximate",
    "approximate_path",
    type=click.Path(path_type=Path, dir_okay=False, exists=True),
    help="An earlier rig calibration, to assign targets a camera does not all see.",
)
@click.option("--pixels", type=click.IntRange(min=2), help="Line width (CSV point lists only).")
def calibrate(
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
        approximate = read_rig(approximate_path) if approximate_path is not None else None
        reports = calibrate_from_captures(captures, distortion=estimate, approximate=approximate)
    if len(reports) < 2:
        raise UserError(f"{captures}: holds {len(reports)} camera(s); a rig needs at least two")
    rig = Rig(
        vehicle=vehicle,
        cameras={
            r.calibration.camera.name: RigCamera(
                camera=r.calibration.camera,
                resolution=r.table,
                reprojection_rms_px=r.calibration.rms_px,
                reprojection_max_px=r.calibration.max_px,
            )
            for r in reports
        },
        created_at=datetime.now(UTC).strftime("%Y-%m-%dT%H:%M:%SZ"),
        source=captures.name,
    )
    write_rig(output, rig)
    _print_reports(reports)
    worst = max(r.calibration.rms_px for r in reports)
    click.echo(f"rig calibration written to {output} (worst reprojection RMS {worst:.3f} px)")
