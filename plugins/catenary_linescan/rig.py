"""The rig calibration file (TOML): output of ``catenary calibrate``, input of processing.

Layout (FORMATS.md "Rig calibration", version 1 of this project's extension)::

    format = "catenary-rig"          # optional; checked when present
    format_version = 1               # optional; default 1
    name = "demo-rig"                # the vehicle geometry, as in the vehicle TOML
    roof_height_mm = 3900.0
    sensor_height_mm = 1100.0
    sensor_baseline_mm = 1800.0
    created_at = "2026-11-23T15:00:00Z"   # optional, informative
    source = "demo-captures.h5"           # optional, informative

    [[cameras]]
    name = "c1"
    pixels = 4096
    matrix = [[m11, m12, m13], [m21, m22, m23]]   # normalised: |(m21, m22, m23)| = 1, m23 > 0
    k1 = 0.0                         # optional radial term (camera.py); default 0
    reprojection_rms_px = 0.08       # optional; default NaN (unknown)
    reprojection_max_px = 0.31       # optional; default NaN
    [cameras.resolution]             # optional; default: derived from the matrix (analytic)
    x_mm = [...]                     # (nx,) increasing
    z_mm = [...]                     # (nz,) increasing
    mm_per_px = [[...], ...]         # (nz, nx)
    filled = [[false, ...], ...]     # optional (nz, nx): nodes interpolated, not measured
    [cameras.measured_resolution]    # optional, same keys: the paper's table measured from
                                     # the targets' face widths, kept as a cross-check

Extra keys are ignored. Errors name the file and the key (``FormatError``).
"""

from __future__ import annotations

import math
import os
import tempfile
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from catenary.domain import VehicleGeometry
from catenary.errors import FormatError, UserError
from catenary.measurement.vehicle import parse_vehicle_geometry
from catenary_linescan.calibration import ResolutionTable, resolution_table_from_camera
from catenary_linescan.camera import LineScanCamera

RIG_FORMAT = "catenary-rig"
RIG_FORMAT_VERSION = 1
DEFAULT_TABLE_X_MM = np.arange(-600.0, 601.0, 100.0)
DEFAULT_TABLE_Z_MM = np.arange(1300.0, 2501.0, 200.0)


@dataclass(frozen=True, eq=False)
class RigCamera:
    """One calibrated camera of a rig with its calibration figures and look-up table."""

    camera: LineScanCamera
    resolution: ResolutionTable
    reprojection_rms_px: float = math.nan
    reprojection_max_px: float = math.nan
    measured_resolution: ResolutionTable | None = None


@dataclass(frozen=True, eq=False)
class Rig:
    """A calibrated rig: the vehicle's geometry and its cameras, by name in file order."""

    vehicle: VehicleGeometry
    cameras: dict[str, RigCamera]
    created_at: str = ""
    source: str = ""

    @property
    def camera_models(self) -> list[LineScanCamera]:
        return [c.camera for c in self.cameras.values()]


def _table_to_toml(table: ResolutionTable) -> dict[str, Any]:
    return {
        "x_mm": table.x_mm.tolist(),
        "z_mm": table.z_mm.tolist(),
        "mm_per_px": np.round(table.mm_per_px, 8).tolist(),
        "filled": table.filled.tolist(),
    }


def _to_toml(rig: Rig) -> dict[str, Any]:
    cameras = []
    for rig_camera in rig.cameras.values():
        entry = rig_camera.camera.to_dict()
        for key in ("reprojection_rms_px", "reprojection_max_px"):
            value = getattr(rig_camera, key)
            if math.isfinite(value):
                entry[key] = round(float(value), 6)
        entry["resolution"] = _table_to_toml(rig_camera.resolution)
        if rig_camera.measured_resolution is not None:
            entry["measured_resolution"] = _table_to_toml(rig_camera.measured_resolution)
        cameras.append(entry)
    return {
        "format": RIG_FORMAT,
        "format_version": RIG_FORMAT_VERSION,
        "name": rig.vehicle.name,
        "roof_height_mm": rig.vehicle.roof_height_mm,
        "sensor_height_mm": rig.vehicle.sensor_height_mm,
        "sensor_baseline_mm": rig.vehicle.sensor_baseline_mm,
        "created_at": rig.created_at,
        "source": rig.source,
        "cameras": cameras,
    }


def write_rig(path: str | os.PathLike[str], rig: Rig) -> None:
    """Write ``rig`` to ``path`` atomically (a temporary file renamed into place)."""
    target = Path(path)
    text = tomli_w.dumps(_to_toml(rig), multiline_strings=False)
    handle, temporary = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.")
    try:
        with os.fdopen(handle, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(temporary, target)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def _array(path: Path, value: Any, key: str, ndim: int) -> np.ndarray[Any, Any]:
    try:
        array = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise FormatError(path, f"{key} must be an array of numbers") from None
    if array.ndim != ndim or array.size == 0 or not np.all(np.isfinite(array)):
        raise FormatError(path, f"{key} must be a non-empty {ndim}-D array of finite numbers")
    return array


def _optional_number(
    path: Path, table: Mapping[str, Any], key: str, where: str, default: float = math.nan
) -> float:
    value = table.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise FormatError(path, f"{where}{key} must be a number, got {value!r}")
    return float(value)


def _table(path: Path, raw: Any, where: str) -> ResolutionTable:
    if not isinstance(raw, dict):
        raise FormatError(path, f"{where} must be a table")
    for key in ("x_mm", "z_mm", "mm_per_px"):
        if key not in raw:
            raise FormatError(path, f"missing key {where}.{key}")
    x = _array(path, raw["x_mm"], f"{where}.x_mm", 1)
    z = _array(path, raw["z_mm"], f"{where}.z_mm", 1)
    values = _array(path, raw["mm_per_px"], f"{where}.mm_per_px", 2)
    filled = np.asarray(raw.get("filled", np.zeros(values.shape, dtype=bool)))
    if np.any(values <= 0):
        raise FormatError(path, f"{where}.mm_per_px must be positive")
    try:
        return ResolutionTable(x, z, values, filled.astype(bool))
    except ValueError as exc:
        raise FormatError(path, f"{where}: {exc}") from None


def _camera(path: Path, raw: Any, index: int) -> RigCamera:
    where = f"cameras[{index}]."
    if not isinstance(raw, dict):
        raise FormatError(path, f"cameras[{index}] must be a table")
    name = raw.get("name")
    if not isinstance(name, str) or not name:
        raise FormatError(path, f"{where}name must be a non-empty string, got {name!r}")
    where = f"cameras[{name}]."
    pixels = raw.get("pixels")
    if isinstance(pixels, bool) or not isinstance(pixels, int) or pixels < 2:
        raise FormatError(path, f"{where}pixels must be an integer >= 2, got {pixels!r}")
    if "matrix" not in raw:
        raise FormatError(path, f"missing key {where}matrix")
    matrix = _array(path, raw["matrix"], f"{where}matrix", 2)
    if matrix.shape != (2, 3):
        raise FormatError(path, f"{where}matrix must be 2x3, got shape {matrix.shape}")
    k1 = _optional_number(path, raw, "k1", where, default=0.0)
    try:
        camera = LineScanCamera(name, pixels, matrix, k1)
    except ValueError as exc:
        raise FormatError(path, f"{where}matrix: {exc}") from None
    resolution = raw.get("resolution")
    if resolution is None:
        table = resolution_table_from_camera(camera, DEFAULT_TABLE_X_MM, DEFAULT_TABLE_Z_MM)
    else:
        table = _table(path, resolution, f"{where}resolution")
    measured = raw.get("measured_resolution")
    return RigCamera(
        camera=camera,
        resolution=table,
        reprojection_rms_px=_optional_number(path, raw, "reprojection_rms_px", where),
        reprojection_max_px=_optional_number(path, raw, "reprojection_max_px", where),
        measured_resolution=None
        if measured is None
        else _table(path, measured, f"{where}measured_resolution"),
    )


def read_rig(path: str | os.PathLike[str]) -> Rig:
    """Read and check a rig calibration TOML file; errors name the file and the key."""
    file = Path(path)
    try:
        data = tomllib.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise UserError(f"{file}: no such file") from None
    except UnicodeDecodeError as exc:
        raise FormatError(file, f"not UTF-8 text ({exc.reason})") from None
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(file, f"not valid TOML: {exc}") from None
    except OSError as exc:
        raise UserError(f"{file}: cannot read ({exc.strerror or exc})") from None
    if data.get("format", RIG_FORMAT) != RIG_FORMAT:
        raise FormatError(file, f"format is {data['format']!r}, not {RIG_FORMAT!r}")
    if data.get("format_version", RIG_FORMAT_VERSION) != RIG_FORMAT_VERSION:
        raise FormatError(file, f"unknown format_version {data['format_version']!r} (known: 1)")
    vehicle = parse_vehicle_geometry(data, file, default_name=file.stem)
    raw_cameras = data.get("cameras")
    if not isinstance(raw_cameras, list) or len(raw_cameras) < 2:
        raise FormatError(file, "cameras must list at least two [[cameras]] tables")
    cameras: dict[str, RigCamera] = {}
    for index, raw in enumerate(raw_cameras):
        rig_camera = _camera(file, raw, index)
        if rig_camera.camera.name in cameras:
            raise FormatError(file, f"camera name {rig_camera.camera.name!r} appears twice")
        cameras[rig_camera.camera.name] = rig_camera
    return Rig(
        vehicle=vehicle,
        cameras=cameras,
        created_at=str(data.get("created_at", "")),
        source=str(data.get("source", "")),
    )
