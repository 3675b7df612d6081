"""The simulated rig: vehicle geometry, cameras (optics and sensor) and lamps, from TOML.

A rig file (``calibration/demo-rig.sim.toml``) holds the FORMATS.md vehicle geometry keys at
its top level (so ``catenary.measurement.vehicle.load_vehicle_geometry`` reads it too), a
``[lighting]`` table and one ``[[cameras]]`` table per camera::

    name = "demo-rig"
    roof_height_mm = 3900.0
    sensor_height_mm = 1100.0
    sensor_baseline_mm = 1800.0

    [lighting]
    kind = "blue_strobe_bandpass"      # or "white_led"
    lamp_x_mm = [-450.0, 0.0, 450.0]   # lamp positions on the roof (roof frame)
    lamp_z_mm = [60.0, 60.0, 60.0]
    lamp_aim_deg = [10.0, 0.0, -10.0]  # optional: beam axis from vertical, + toward +x
    beam_sigma_deg = 30.0              # optional: Gaussian beam profile

    [[cameras]]
    name = "cam1"
    pixels = 4096
    pixel_pitch_um = 7.0
    focal_length_mm = 32.0
    x_mm = -700.0                      # lens centre in the roof frame
    z_mm = 100.0
    tilt_deg = 24.8                    # optical axis from vertical, + toward +x
    k1 = 0.0                           # radial distortion (catenary_linescan.camera)
    f_number = 8.0
    focus_distance_mm = 2000.0         # along the optical axis
    bit_depth = 8
    read_noise_e = 20.0
    full_well_e = 20000.0
    gain_dn_per_e = 0.01275            # grey levels per electron
    # optional: principal_point_px (default (pixels - 1) / 2), black_level_dn (0),
    # lens_blur_px (0.35: aberrations, Gaussian sigma), prnu (0.005: pixel gain spread),
    # exposure (1.0: the exposure time relative to the radiometry's unit exposure)

Every length is in the unit its name says. The true camera model of each camera is
``camera_from_pose`` of its mounting (focal length over pixel pitch in pixels).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from catenary.arrays import FloatArray
from catenary.domain import VehicleGeometry
from catenary.errors import FormatError, UserError
from catenary.measurement.vehicle import parse_vehicle_geometry
from catenary_linescan.camera import LineScanCamera, camera_from_pose

__all__ = ["LIGHTING_KINDS", "Lamp", "SimCamera", "SimRig", "load_rig", "parse_rig"]

LIGHTING_KINDS = ("blue_strobe_bandpass", "white_led")
"""Active lighting a rig can carry: the paper's blue stroboscopic LEDs behind narrow band-pass
filters, or plain white LED lamps (the paper's figure 12 compares the two)."""

_CAMERA_REQUIRED: dict[str, tuple[type, ...]] = {
    "name": (str,),
    "pixels": (int,),
    "pixel_pitch_um": (int, float),
    "focal_length_mm": (int, float),
    "x_mm": (int, float),
    "z_mm": (int, float),
    "tilt_deg": (int, float),
    "k1": (int, float),
    "f_number": (int, float),
    "focus_distance_mm": (int, float),
    "bit_depth": (int,),
    "read_noise_e": (int, float),
    "full_well_e": (int, float),
    "gain_dn_per_e": (int, float),
}
_CAMERA_OPTIONAL: dict[str, float] = {
    "black_level_dn": 0.0,
    "lens_blur_px": 0.35,
    "prnu": 0.005,
    "exposure": 1.0,
}
_POSITIVE = {
    "pixels",
    "pixel_pitch_um",
    "focal_length_mm",
    "f_number",
    "focus_distance_mm",
    "bit_depth",
    "full_well_e",
    "gain_dn_per_e",
}


@dataclass(frozen=True)
class SimCamera:
    """One simulated line-scan camera: mounting, lens and sensor.

    Lengths in [mm] unless the name says otherwise; ``tilt_deg`` is the optical axis from
    vertical, positive toward ``+x``; ``gain_dn_per_e`` converts electrons to grey levels;
    ``exposure`` scales the electrons collected (the exposure time relative to the unit of
    :mod:`.radiometry`).
    """

    name: str
    pixels: int
    pixel_pitch_um: float
    focal_length_mm: float
    x_mm: float
    z_mm: float
    tilt_deg: float
    k1: float
    f_number: float
    focus_distance_mm: float
    bit_depth: int
    read_noise_e: float
    full_well_e: float
    gain_dn_per_e: float
    principal_point_px: float
    black_level_dn: float = 0.0
    lens_blur_px: float = 0.35
    prnu: float = 0.005
    exposure: float = 1.0

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: focal length over pixel pitch."""
        return self.focal_length_mm / (self.pixel_pitch_um * 1e-3)

    @property
    def max_dn(self) -> int:
        """Largest grey level of the camera's bit depth."""
        return (1 << self.bit_depth) - 1

    def model(self) -> LineScanCamera:
        """The camera's TRUE projective model (2x3 matrix and ``k1``) from its mounting."""
        return camera_from_pose(
            self.name,
            self.pixels,
            self.x_mm,
            self.z_mm,
            self.tilt_deg,
            self.focal_px,
            self.principal_point_px,
            self.k1,
        )

    def nominal_model(self) -> LineScanCamera:
        """The model of the mounting drawing: the design pose and focal length, the principal
        point at the line's middle, no distortion (to assign calibration targets)."""
        return camera_from_pose(
            self.name,
            self.pixels,
            self.x_mm,
            self.z_mm,
            self.tilt_deg,
            self.focal_px,
            (self.pixels - 1) / 2.0,
        )

    def defocus_diameter_px(self, depth_mm: ArrayLike) -> FloatArray:
        """Diameter of the thin-lens blur disc on the sensor [px] for objects at ``depth_mm``.

        ``b = f² / N · |D - Df| / (D · (Df - f))`` with focal length ``f``, f-number ``N``,
        focus distance ``Df`` and object distance ``D`` along the optical axis (all mm), over
        the pixel pitch.
        """
        depth = np.maximum(np.asarray(depth_mm, dtype=np.float64), self.focal_length_mm * 2)
        f = self.focal_length_mm
        focus = self.focus_distance_mm
        blur_mm = (f * f / self.f_number) * np.abs(depth - focus) / (depth * (focus - f))
        return np.asarray(blur_mm / (self.pixel_pitch_um * 1e-3), dtype=np.float64)

    def diffraction_sigma_px(self, wavelength_nm: float) -> float:
        """Gaussian sigma [px] of the diffraction-limited spot: ``0.42 λ N`` over the pitch."""
        return 0.42 * wavelength_nm * 1e-3 * self.f_number / self.pixel_pitch_um


@dataclass(frozen=True)
class Lamp:
    """An active lamp on the roof: position [mm] and beam axis from vertical [deg]."""

    x_mm: float
    z_mm: float
    aim_deg: float = 0.0


@dataclass(frozen=True)
class SimRig:
    """A simulated rig: the vehicle geometry, its cameras and its lamps."""

    name: str
    vehicle: VehicleGeometry
    cameras: tuple[SimCamera, ...]
    lighting: str
    lamps: tuple[Lamp, ...]
    beam_sigma_deg: float = 30.0
    text: str = ""  # the TOML it was read from, kept for the ground truth

    def camera(self, name: str) -> SimCamera:
        """The camera called ``name``; ``UserError`` listing the rig's cameras otherwise."""
        for camera in self.cameras:
            if camera.name == name:
                return camera
        names = ", ".join(c.name for c in self.cameras)
        raise UserError(f"rig {self.name!r} has no camera {name!r} (cameras: {names})")

    def models(self) -> dict[str, LineScanCamera]:
        """The true camera models by name."""
        return {camera.name: camera.model() for camera in self.cameras}

    def nominal_models(self) -> dict[str, LineScanCamera]:
        """The mounting drawing's camera models by name (:meth:`SimCamera.nominal_model`)."""
        return {camera.name: camera.nominal_model() for camera in self.cameras}


def _number(
    table: Mapping[str, Any], key: str, path: object, where: str, kinds: tuple[type, ...]
) -> Any:
    if key not in table:
        raise FormatError(path, f"missing key {where}{key}")
    value = table[key]
    if isinstance(value, bool) or not isinstance(value, kinds):
        kind = "an integer" if kinds == (int,) else "a string" if kinds == (str,) else "a number"
        raise FormatError(path, f"key {where}{key} must be {kind}, got {value!r}")
    if isinstance(value, float) and not math.isfinite(value):
        raise FormatError(path, f"key {where}{key} must be finite, got {value!r}")
    return value


def _parse_camera(table: Any, index: int, path: object) -> SimCamera:
    where = f"cameras[{index}]."
    if not isinstance(table, dict):
        raise FormatError(path, f"cameras[{index}] must be a table")
    unknown = sorted(set(table) - set(_CAMERA_REQUIRED) - set(_CAMERA_OPTIONAL))
    unknown = [key for key in unknown if key != "principal_point_px"]
    if unknown:
        raise FormatError(path, f"unknown key {where}{unknown[0]}")
    values: dict[str, Any] = {}
    for key, kinds in _CAMERA_REQUIRED.items():
        value = _number(table, key, path, where, kinds)
        if key in _POSITIVE and value <= 0:
            raise FormatError(path, f"key {where}{key} must be positive, got {value!r}")
        values[key] = float(value) if float in kinds else value
    for key, default in _CAMERA_OPTIONAL.items():
        values[key] = (
            float(_number(table, key, path, where, (int, float))) if key in table else default
        )
        if values[key] < 0:
            raise FormatError(path, f"key {where}{key} must not be negative, got {values[key]!r}")
    if not values["name"] or "/" in values["name"]:
        raise FormatError(path, f"key {where}name must be a non-empty name without '/'")
    if not 1 <= values["bit_depth"] <= 16:
        raise FormatError(path, f"key {where}bit_depth must be 1-16, got {values['bit_depth']}")
    if values["exposure"] <= 0:
        raise FormatError(path, f"key {where}exposure must be positive")
    if values["read_noise_e"] < 0:
        raise FormatError(path, f"key {where}read_noise_e must not be negative")
    if values["focus_distance_mm"] <= 2 * values["focal_length_mm"]:
        raise FormatError(path, f"key {where}focus_distance_mm is inside twice the focal length")
    if abs(values["tilt_deg"]) >= 80:
        raise FormatError(path, f"key {where}tilt_deg must be within ±80°")
    if "principal_point_px" in table:
        values["principal_point_px"] = float(
            _number(table, "principal_point_px", path, where, (int, float))
        )
    else:
        values["principal_point_px"] = (values["pixels"] - 1) / 2.0
    return SimCamera(**values)


def parse_rig(table: Mapping[str, Any], path: object, *, text: str = "") -> SimRig:
    """A :class:`SimRig` from a parsed rig TOML table; ``FormatError`` naming the key."""
    vehicle = parse_vehicle_geometry(table, path, default_name=Path(str(path)).stem)
    cameras_raw = table.get("cameras")
    if not isinstance(cameras_raw, list) or not cameras_raw:
        raise FormatError(path, "needs at least one [[cameras]] table")
    cameras = tuple(_parse_camera(raw, i, path) for i, raw in enumerate(cameras_raw))
    names = [c.name for c in cameras]
    duplicate = next((n for n in names if names.count(n) > 1), None)
    if duplicate is not None:
        raise FormatError(path, f"camera name {duplicate!r} is used twice")
    lighting = table.get("lighting")
    if not isinstance(lighting, dict):
        raise FormatError(path, "needs a [lighting] table")
    kind = lighting.get("kind")
    if kind not in LIGHTING_KINDS:
        raise FormatError(
            path, f"key lighting.kind must be one of {', '.join(LIGHTING_KINDS)}, got {kind!r}"
        )
    xs = lighting.get("lamp_x_mm")
    zs = lighting.get("lamp_z_mm")
    aims = lighting.get("lamp_aim_deg", [0.0] * len(xs) if isinstance(xs, list) else None)
    for key, values in (("lamp_x_mm", xs), ("lamp_z_mm", zs), ("lamp_aim_deg", aims)):
        if (
            not isinstance(values, list)
            or not values
            or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in values)
        ):
            raise FormatError(path, f"key lighting.{key} must be a non-empty list of numbers")
    assert isinstance(xs, list) and isinstance(zs, list) and isinstance(aims, list)
    if not len(xs) == len(zs) == len(aims):
        raise FormatError(path, "lighting.lamp_x_mm, lamp_z_mm and lamp_aim_deg differ in length")
    beam = lighting.get("beam_sigma_deg", 30.0)
    if isinstance(beam, bool) or not isinstance(beam, int | float) or not 1 <= beam <= 90:
        raise FormatError(path, f"key lighting.beam_sigma_deg must be 1-90, got {beam!r}")
    lamps = tuple(Lamp(float(x), float(z), float(a)) for x, z, a in zip(xs, zs, aims, strict=True))
    return SimRig(
        name=vehicle.name,
        vehicle=vehicle,
        cameras=cameras,
        lighting=str(kind),
        lamps=lamps,
        beam_sigma_deg=float(beam),
        text=text,
    )


def load_rig(path: str | Path) -> SimRig:
    """Read a simulated rig TOML file; ``UserError``/``FormatError`` naming file and key."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise UserError(f"{file}: no such rig file") from None
    except UnicodeDecodeError:
        raise FormatError(file, "not UTF-8 text") from None
    except OSError as exc:
        raise UserError(f"{file}: cannot read ({exc.strerror or exc})") from None
    try:
        table = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise FormatError(file, f"not valid TOML: {exc}") from None
    return parse_rig(table, file, text=text)
