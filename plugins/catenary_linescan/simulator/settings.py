"""Simulation settings: what ``open_simulation`` and ``catenary simulate`` accept.

Keys of the settings mapping (all optional; units in the names):

=========================  ====================================================================
``rig``                    rig TOML path (default: ``calibration/demo-rig.sim.toml`` of the
                           source tree) or a :class:`~.rig.SimRig`
``length_m``               true length of the run (300)
``seed``                   integer seed of the motion (speed, body pose, encoder errors), sky
                           and noise, and of the scene unless ``scene_seed`` is given (0)
``scene_seed``             integer seed of the scene alone (masts, wires, fittings, wear); none:
                           ``seed``. Runs with one ``scene_seed`` (and the same section:
                           ``length_m``, ``start_chainage_m``, ``overlap``, ``curve_*``,
                           ``wire_type``, rig roof height) and different ``seed`` see the same
                           line with different motion and noise (repeatability)
``lighting``               ``night``, ``day-filter`` or ``day-white`` (``night``)
``overlap``                lay out an overlap (two contact wires) mid-run (true)
``sun_blind``              name of a camera blinded by the sun over ``sun_blind_span`` (none)
``sun_blind_span``         fractions of the run ``[from, to]`` the sun blinds it ([0.3, 0.6])
``sun_blind_strength``     the glare's peak strength (1: the camera saturates across its line;
                           0.02-0.3: only the part of the line near the sun saturates, the
                           rest is veiled)
``speed_kmh``              train speed (60)
``scan_rate_hz``           camera trigger rate (1000)
``direction``              ``increasing`` or ``decreasing`` chainage (``increasing``)
``start_chainage_m``       true chainage of the first scan (12000)
``line``, ``track``        identifiers for the header and the mast register
``wire_type``              contact wire profile (``CTA120``)
``curve_radius_m``         none: the seed decides; 0: straight; > 0: a curve of that radius
``curve_direction``        +1 bends right, -1 left, 0: the seed decides
``turnout_angle_deg``      none: no turnout; 2-10: a turnout mid-run whose diverging contact
                           wire crosses the main one at this angle in plan (needs ``overlap``
                           false: a section has an overlap or a turnout)
``encoder_scale_error``    relative (e.g. 0.003); none: drawn from the seed
``start_chainage_error_m`` header minus true start chainage; none: drawn from the seed
``roll_std_deg``, ``lateral_std_mm``, ``bounce_std_mm``: body motion (0.25, 8, 5)
``sensor_rate_hz``         displacement sensor sample rate (200)
``sensor_noise_mm``        displacement sensor noise (0.3)
``noise``                  shot and read noise on (true)
``shot_noise``             ``poisson`` or ``gaussian`` (``poisson``)
``blur``                   optical blur on (true)
``subsamples``             sub-pixels per pixel (2; coverage is exact whatever it is)
``chunk_scans``            scans rendered at a time (256): memory, not results, depends on it
``started_at``             ISO 8601 UTC start time (fixed per lighting, so runs are repeatable)
=========================  ====================================================================

Errors a user can make raise :class:`~catenary.errors.UserError` naming the key and value.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, fields
from importlib.resources import files
from pathlib import Path
from typing import Any

from catenary.errors import UserError

from .motion import MotionParams
from .radiometry import CONDITIONS
from .rig import SimRig, load_rig
from .scene import SceneParams
from .sensor import SHOT_NOISE

__all__ = ["DEMO_RIG_PATH", "SimulationSettings", "parse_settings"]

DEMO_RIG_PATH = Path(str(files("catenary_calibration").joinpath("demo-rig.sim.toml")))
"""The demo rig (``calibration/demo-rig.sim.toml``, shipped as package ``catenary_calibration``)."""


@dataclass(frozen=True)
class SimulationSettings:
    """Validated simulation settings (module docstring)."""

    rig: SimRig
    length_m: float = 300.0
    seed: int = 0
    scene_seed: int | None = None
    lighting: str = "night"
    overlap: bool = True
    sun_blind: str | None = None
    sun_blind_span: tuple[float, float] = (0.3, 0.6)
    sun_blind_strength: float = 1.0
    speed_kmh: float = 60.0
    scan_rate_hz: float = 1000.0
    direction: str = "increasing"
    start_chainage_m: float = 12000.0
    line: str = "demo-line"
    track: str = "1"
    wire_type: str = "CTA120"
    curve_radius_m: float | None = None
    curve_direction: int = 0
    turnout_angle_deg: float | None = None
    encoder_scale_error: float | None = None
    start_chainage_error_m: float | None = None
    roll_std_deg: float = 0.25
    lateral_std_mm: float = 8.0
    bounce_std_mm: float = 5.0
    sensor_rate_hz: float = 200.0
    sensor_noise_mm: float = 0.3
    noise: bool = True
    shot_noise: str = "poisson"
    blur: bool = True
    subsamples: int = 2
    chunk_scans: int = 256
    started_at: str | None = None

    @property
    def scene_rng_seed(self) -> int:
        """The seed the scene is generated from: ``scene_seed``, or ``seed`` without it."""
        return self.seed if self.scene_seed is None else self.scene_seed

    def scene_params(self) -> SceneParams:
        """The scene around the run's chainages: from its start up, or down when decreasing."""
        decreasing = self.direction == "decreasing"
        return SceneParams(
            length_m=self.length_m,
            start_chainage_m=self.start_chainage_m - (self.length_m if decreasing else 0.0),
            line=self.line,
            track=self.track,
            wire_type=self.wire_type,
            overlap=self.overlap,
            curve_radius_m=self.curve_radius_m,
            curve_direction=self.curve_direction,
            roof_height_mm=self.rig.vehicle.roof_height_mm,
            turnout_angle_deg=self.turnout_angle_deg,
        )

    def motion_params(self) -> MotionParams:
        return MotionParams(
            speed_kmh=self.speed_kmh,
            scan_rate_hz=self.scan_rate_hz,
            direction=self.direction,
            encoder_scale_error=self.encoder_scale_error,
            start_chainage_error_m=self.start_chainage_error_m,
            roll_std_deg=self.roll_std_deg,
            lateral_std_mm=self.lateral_std_mm,
            bounce_std_mm=self.bounce_std_mm,
            sensor_rate_hz=self.sensor_rate_hz,
            sensor_noise_mm=self.sensor_noise_mm,
        )

    def as_dict(self) -> dict[str, Any]:
        """Plain values (the rig by name) for the ground truth's record; ``scene_seed`` only
        when given (so that a record without it reads as before it existed)."""
        out: dict[str, Any] = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "scene_seed" and value is None:
                continue
            out[f.name] = value.name if isinstance(value, SimRig) else value
        return out


_FLOATS = {
    "length_m",
    "sun_blind_strength",
    "speed_kmh",
    "scan_rate_hz",
    "start_chainage_m",
    "roll_std_deg",
    "lateral_std_mm",
    "bounce_std_mm",
    "sensor_rate_hz",
    "sensor_noise_mm",
}
_OPTIONAL_FLOATS = {
    "curve_radius_m",
    "encoder_scale_error",
    "start_chainage_error_m",
    "turnout_angle_deg",
}
_INTS = {"seed", "scene_seed", "curve_direction", "subsamples", "chunk_scans"}
_BOOLS = {"overlap", "noise", "blur"}
_NULLABLE = _OPTIONAL_FLOATS | {"scene_seed", "sun_blind", "started_at", "rig"}
_STRINGS = {"line", "track", "wire_type", "direction", "lighting", "shot_noise"}


def _fail(key: str, value: Any, expected: str) -> UserError:
    return UserError(f"simulation setting {key} = {value!r}: expected {expected}")


def parse_settings(settings: Mapping[str, Any]) -> SimulationSettings:
    """Validate a settings mapping (module docstring) into :class:`SimulationSettings`."""
    known = {f.name for f in fields(SimulationSettings)}
    unknown = sorted(set(settings) - known)
    if unknown:
        raise UserError(f"unknown simulation setting {unknown[0]!r}")
    values: dict[str, Any] = {}
    for key, value in settings.items():
        if value is None and key in _NULLABLE:
            continue
        if key in _FLOATS | _OPTIONAL_FLOATS:
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise _fail(key, value, "a number")
            if not math.isfinite(float(value)):
                raise _fail(key, value, "a finite number")
            values[key] = float(value)
        elif key in _INTS:
            if isinstance(value, bool) or not isinstance(value, int):
                raise _fail(key, value, "an integer")
            values[key] = int(value)
        elif key in _BOOLS:
            if not isinstance(value, bool):
                raise _fail(key, value, "true or false")
            values[key] = value
        elif key in _STRINGS | {"sun_blind", "started_at"}:
            if not isinstance(value, str):
                raise _fail(key, value, "a string")
            values[key] = value
        elif key == "sun_blind_span":
            try:
                low, high = (float(v) for v in value)
            except (TypeError, ValueError):
                raise _fail(key, value, "two fractions [from, to]") from None
            if not 0.0 <= low < high <= 1.0:
                raise _fail(key, value, "two fractions 0 <= from < to <= 1")
            values[key] = (low, high)
        elif key == "rig":
            values[key] = value
    rig = values.pop("rig", DEMO_RIG_PATH)
    if not isinstance(rig, SimRig):
        if not isinstance(rig, str | Path):
            raise _fail("rig", rig, "a rig TOML path")
        rig = load_rig(rig)
    parsed = SimulationSettings(rig=rig, **values)
    if parsed.length_m <= 0 or parsed.length_m > 100000:
        raise _fail("length_m", parsed.length_m, "a length of 0-100000 m")
    if parsed.lighting not in CONDITIONS:
        raise _fail("lighting", parsed.lighting, " or ".join(CONDITIONS))
    if parsed.shot_noise not in SHOT_NOISE:
        raise _fail("shot_noise", parsed.shot_noise, " or ".join(SHOT_NOISE))
    if parsed.seed < 0:
        raise _fail("seed", parsed.seed, "a non-negative integer")
    if parsed.scene_seed is not None and parsed.scene_seed < 0:
        raise _fail("scene_seed", parsed.scene_seed, "a non-negative integer")
    if not 1 <= parsed.subsamples <= 64:
        raise _fail("subsamples", parsed.subsamples, "1-64")
    if not 1 <= parsed.chunk_scans <= 65536:
        raise _fail("chunk_scans", parsed.chunk_scans, "1-65536")
    if parsed.curve_direction not in (-1, 0, 1):
        raise _fail("curve_direction", parsed.curve_direction, "-1, 0 or 1")
    if parsed.curve_radius_m is not None and (
        parsed.curve_radius_m < 0 or 0 < parsed.curve_radius_m < 150
    ):
        raise _fail("curve_radius_m", parsed.curve_radius_m, "0 (straight) or at least 150 m")
    if parsed.turnout_angle_deg is not None:
        if not 2.0 <= parsed.turnout_angle_deg <= 10.0:
            raise _fail("turnout_angle_deg", parsed.turnout_angle_deg, "2-10 degrees or none")
        if parsed.overlap:
            raise _fail(
                "turnout_angle_deg",
                parsed.turnout_angle_deg,
                "overlap false with it (a section has an overlap or a turnout)",
            )
    if not 0.0 < parsed.sun_blind_strength <= 1.0:
        raise _fail("sun_blind_strength", parsed.sun_blind_strength, "a strength 0 < s <= 1")
    if parsed.sun_blind is not None:
        rig.camera(parsed.sun_blind)  # UserError naming the rig's cameras
    parsed.motion_params().check()
    return parsed
