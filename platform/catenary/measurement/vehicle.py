"""Vehicle compensation: roof frame <-> track frame from the car body's displacement sensors.

The model is FORMATS.md's "Vehicle compensation model": a rigid car body whose left and right
displacement sensors (``left_mm``, ``right_mm``, positive = body higher than nominal ride),
``sensor_baseline_mm`` apart, give its roll and bounce, and whose lateral sensor
(``lateral_mm``, positive = body to the right) gives its sway. With

    phi = atan((left_mm - right_mm) / sensor_baseline_mm)            (positive = left side up)
    B   = (lateral_mm, sensor_height_mm + (left_mm + right_mm) / 2)  (track frame)
    O   = B + (roof_height_mm - sensor_height_mm) * (sin phi, cos phi)

a roof-frame point ``(x_r, z_r)`` is, in the track frame,

    p = O + x_r * (cos phi, -sin phi) + z_r * (sin phi, cos phi)

and the inverse projects ``p - O`` on the body's two axes. Every function is vectorised and
broadcasts its array arguments against each other (NumPy rules), e.g. ``[n]`` wire positions
with ``[n]`` sensor values for one wire per scan, or ``[n, m]`` positions with ``[n, 1]``
sensor values for ``m`` wires per scan.

``load_vehicle_geometry`` reads the vehicle TOML of FORMATS.md.
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray
from catenary.domain import NAME_LENGTH, VehicleGeometry
from catenary.errors import FormatError, UserError
from catenary.text import length_problem

__all__ = [
    "load_vehicle_geometry",
    "parse_vehicle_geometry",
    "roll_rad",
    "roof_to_track",
    "track_to_roof",
]

_NUMERIC_KEYS = ("roof_height_mm", "sensor_height_mm", "sensor_baseline_mm")


def roll_rad(left_mm: ArrayLike, right_mm: ArrayLike, baseline_mm: ArrayLike) -> FloatArray:
    """Roll of the car body, positive when the left side is up.

    ``phi = atan((left_mm - right_mm) / baseline_mm)``.

    Parameters
    ----------
    left_mm, right_mm : array_like, broadcastable
        Vertical displacement of the body at the left and right sensor [mm], positive up.
    baseline_mm : array_like
        Distance between the two sensors [mm], positive.

    Returns
    -------
    ndarray of float64, the broadcast shape of the inputs
        Roll [rad].
    """
    left = np.asarray(left_mm, dtype=np.float64)
    right = np.asarray(right_mm, dtype=np.float64)
    baseline = np.asarray(baseline_mm, dtype=np.float64)
    return np.asarray(np.arctan((left - right) / baseline), dtype=np.float64)


def _body_pose(
    left_mm: ArrayLike,
    right_mm: ArrayLike,
    lateral_mm: ArrayLike,
    geometry: VehicleGeometry,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``(sin phi, cos phi, O_x, O_z)``: the body's roll and the roof origin in the track frame."""
    left = np.asarray(left_mm, dtype=np.float64)
    right = np.asarray(right_mm, dtype=np.float64)
    lateral = np.asarray(lateral_mm, dtype=np.float64)
    phi = roll_rad(left, right, geometry.sensor_baseline_mm)
    sin_phi = np.sin(phi)
    cos_phi = np.cos(phi)
    above_b_mm = geometry.roof_height_mm - geometry.sensor_height_mm
    origin_x = lateral + above_b_mm * sin_phi
    origin_z = geometry.sensor_height_mm + 0.5 * (left + right) + above_b_mm * cos_phi
    return sin_phi, cos_phi, origin_x, origin_z


def roof_to_track(
    x_roof_mm: ArrayLike,
    z_roof_mm: ArrayLike,
    left_mm: ArrayLike,
    right_mm: ArrayLike,
    lateral_mm: ArrayLike,
    geometry: VehicleGeometry,
) -> tuple[FloatArray, FloatArray]:
    """Roof-frame points to the track frame (stagger and height above top of rail).

    Parameters
    ----------
    x_roof_mm, z_roof_mm : array_like
        Point in the roof frame [mm]: ``x`` lateral (positive right), ``z`` up.
    left_mm, right_mm : array_like
        Body displacement at the left and right sensor [mm], positive = body higher.
    lateral_mm : array_like
        Lateral displacement of the body centre line [mm], positive = body to the right.
    geometry : VehicleGeometry
        Roof and sensor heights and the sensor baseline [mm].

    All array arguments broadcast together.

    Returns
    -------
    (stagger_mm, height_mm) : ndarrays of float64, the broadcast shape
        The point in the track frame [mm].
    """
    x_r = np.asarray(x_roof_mm, dtype=np.float64)
    z_r = np.asarray(z_roof_mm, dtype=np.float64)
    sin_phi, cos_phi, origin_x, origin_z = _body_pose(left_mm, right_mm, lateral_mm, geometry)
    stagger_mm = origin_x + x_r * cos_phi + z_r * sin_phi
    height_mm = origin_z - x_r * sin_phi + z_r * cos_phi
    return np.asarray(stagger_mm, dtype=np.float64), np.asarray(height_mm, dtype=np.float64)


def track_to_roof(
    stagger_mm: ArrayLike,
    height_mm: ArrayLike,
    left_mm: ArrayLike,
    right_mm: ArrayLike,
    lateral_mm: ArrayLike,
    geometry: VehicleGeometry,
) -> tuple[FloatArray, FloatArray]:
    """Track-frame points to the roof frame: the exact inverse of :func:`roof_to_track`.

    Parameters
    ----------
    stagger_mm, height_mm : array_like
        Point in the track frame [mm]: stagger (positive right), height above top of rail.
    left_mm, right_mm, lateral_mm : array_like
        The displacement sensors [mm], as in :func:`roof_to_track`.
    geometry : VehicleGeometry
        Roof and sensor heights and the sensor baseline [mm].

    Returns
    -------
    (x_roof_mm, z_roof_mm) : ndarrays of float64, the broadcast shape
        The point in the roof frame [mm].
    """
    stagger = np.asarray(stagger_mm, dtype=np.float64)
    height = np.asarray(height_mm, dtype=np.float64)
    sin_phi, cos_phi, origin_x, origin_z = _body_pose(left_mm, right_mm, lateral_mm, geometry)
    dx = stagger - origin_x
    dz = height - origin_z
    x_roof_mm = dx * cos_phi - dz * sin_phi
    z_roof_mm = dx * sin_phi + dz * cos_phi
    return np.asarray(x_roof_mm, dtype=np.float64), np.asarray(z_roof_mm, dtype=np.float64)


def parse_vehicle_geometry(
    table: Mapping[str, object], path: object, *, prefix: str = "", default_name: str = ""
) -> VehicleGeometry:
    """A :class:`VehicleGeometry` from a parsed TOML table (the vehicle TOML's keys).

    ``prefix`` is prepended to key names in error messages (e.g. ``"vehicle."`` when the
    table is nested in a rig calibration); ``name`` defaults to ``default_name`` when absent.
    Raises :class:`FormatError` naming ``path`` and the key for a missing, non-numeric,
    non-finite or non-positive length, a roof not above the sensors (the roof origin O lies
    ``roof_height_mm - sensor_height_mm`` above the sensors' reference point B), or a
    non-string name.
    """
    name = table.get("name", default_name)
    if not isinstance(name, str):
        raise FormatError(path, f"key {prefix}name must be a string, got {name!r}")
    problem = length_problem(f"key {prefix}name", name, NAME_LENGTH)
    if problem is not None:
        raise FormatError(path, problem)
    values: dict[str, float] = {}
    for key in _NUMERIC_KEYS:
        if key not in table:
            raise FormatError(path, f"missing key {prefix}{key}")
        value = table[key]
        # bool is an int subclass: `true` is not a length.
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise FormatError(path, f"key {prefix}{key} must be a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number) or number <= 0.0:
            raise FormatError(path, f"key {prefix}{key} must be positive, got {value!r}")
        values[key] = number
    roof, sensor = values["roof_height_mm"], values["sensor_height_mm"]
    if roof <= sensor:
        raise FormatError(
            path,
            f"key {prefix}roof_height_mm = {table['roof_height_mm']!r} is not above "
            f"{prefix}sensor_height_mm = {table['sensor_height_mm']!r}: the roof that carries "
            "the cameras is above the car body's displacement sensors",
        )
    return VehicleGeometry(
        name=name,
        roof_height_mm=values["roof_height_mm"],
        sensor_height_mm=values["sensor_height_mm"],
        sensor_baseline_mm=values["sensor_baseline_mm"],
    )


def load_vehicle_geometry(path: str | Path) -> VehicleGeometry:
    """Read a vehicle geometry TOML file (FORMATS.md "Vehicle geometry: TOML").

    Keys ``roof_height_mm``, ``sensor_height_mm`` and ``sensor_baseline_mm`` are required,
    numeric and positive, the roof above the sensors; ``name`` is optional (default: the file's
    stem). Extra keys are ignored. Raises :class:`UserError` if the file cannot be read and
    :class:`FormatError` (naming the file and the key) if it is not valid TOML or a key is
    wrong.
    """
    file = Path(path)
    try:
        text = file.read_bytes().decode("utf-8")
    except FileNotFoundError:
        raise UserError(f"{file}: no such file") from None
    except UnicodeDecodeError as exc:
        raise FormatError(file, f"not UTF-8 text ({exc.reason})") from None
    except OSError as exc:
        raise UserError(f"{file}: cannot read ({exc.strerror or exc})") from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(file, f"not valid TOML: {exc}") from None
    return parse_vehicle_geometry(table, file, default_name=file.stem)
