"""Generated rigs: 2-6 line-scan cameras across a roof, laid out from a seed.

:func:`generate_rig` builds the rig TOML table (:mod:`.rig`) a designer would draw for a
given number of cameras, pixels per line and bit depth, and parses it, so a generated rig is
validated like a file and its TOML text (``SimRig.text``) reproduces it:

- **Mounting**: the cameras spread evenly across the roof, the outer ones 450-800 mm from the
  centre (a few tens of mm of jitter each), 70-150 mm above the roof origin; each is tilted
  to the middle of the angles under which it sees the corners of the measuring field
  ``x = ±field_half_width_mm`` at ``field_z_mm`` (roof frame).
- **Lens**: the focal length [px] spans that field plus ``margin_deg`` on each side with the
  line's pixels; the pixel pitch is a common one for the line length (:data:`PIXEL_PITCH_UM`),
  the focal length in mm follows. Focus at the harmonic mean of the nearest and farthest
  depths (where the defocus at both ends is equal); the f-number is the smallest of
  :data:`F_NUMBERS` that keeps that defocus within ``max_defocus_px`` (the largest when none
  does: long lines of small pixels are then limited by their depth of field). A little
  barrel distortion (``k1`` 0 to -0.02) and a principal point up to 0.2 % of the line off
  its middle; the mounting drawing (``SimCamera.nominal_model``) knows neither.
- **Sensor**: the demo rig's (20 e- read noise, 20,000 e- full well); the gain fills the
  bit depth's range at the full well at f/8. The operator makes the lines look alike
  whatever the aperture: for a smaller one (``N > 8``) the gain is raised by ``(N / 8)²``,
  for a larger one the exposure time is shortened by that factor (the gain cannot go below
  the full well's filling the range without the sensor saturating below the range's top,
  where the processor cannot tell a clipped face from a lit one). Black level 2 DN at 8
  bits.
- **Lamps**: the demo rig's three blue strobes behind band-pass filters.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import tomli_w

from .rig import SimRig, parse_rig

__all__ = ["F_NUMBERS", "PIXEL_PITCH_UM", "generate_rig"]

PIXEL_PITCH_UM: dict[int, tuple[float, ...]] = {
    2048: (10.0, 14.0),
    4096: (7.0, 10.0),
    8192: (5.0, 7.0),
    16384: (3.5, 5.0),
}
"""Pixel pitches [µm] of common line-scan sensors by line length [px]."""

F_NUMBERS = (4.0, 5.6, 8.0, 11.0, 16.0)
READ_NOISE_E = 20.0
FULL_WELL_E = 20000.0


def _corner_angles_deg(
    x_mm: float, z_mm: float, half_width_mm: float, field_z_mm: tuple[float, float]
) -> tuple[float, float]:
    """Smallest and largest ray angle from vertical [deg] to the field's corners."""
    xs = np.array([-half_width_mm, half_width_mm])[:, None]
    zs = np.array(field_z_mm)[None, :]
    angles = np.degrees(np.arctan2(xs - x_mm, zs - z_mm))
    return float(angles.min()), float(angles.max())


def _depths_mm(
    x_mm: float, z_mm: float, tilt_deg: float, half_width_mm: float, field_z_mm: tuple[float, float]
) -> tuple[float, float]:
    """Nearest and farthest depth [mm] along the optical axis of the field's corners."""
    tilt = math.radians(tilt_deg)
    xs = np.array([-half_width_mm, half_width_mm])[:, None] - x_mm
    zs = np.array(field_z_mm)[None, :] - z_mm
    depth = xs * math.sin(tilt) + zs * math.cos(tilt)
    return float(depth.min()), float(depth.max())


def generate_rig(
    seed: int,
    *,
    cameras: int,
    pixels: int,
    bit_depth: int,
    roof_height_mm: float = 3900.0,
    sensor_height_mm: float = 1100.0,
    sensor_baseline_mm: float = 1800.0,
    field_half_width_mm: float = 600.0,
    field_z_mm: tuple[float, float] = (1250.0, 2550.0),
    margin_deg: float = 2.0,
    max_defocus_px: float = 5.0,
    name: str | None = None,
) -> SimRig:
    """A rig of ``cameras`` cameras of ``pixels`` px at ``bit_depth`` bits (module docstring).

    ``pixels`` is a key of :data:`PIXEL_PITCH_UM`; every camera sees ``x`` within
    ``±field_half_width_mm`` at every height in ``field_z_mm`` (roof frame) with
    ``margin_deg`` to spare. ``ValueError`` for counts outside 2-6, bit depths outside 8-16.
    """
    if not 2 <= cameras <= 6:
        raise ValueError(f"a generated rig has 2-6 cameras, got {cameras}")
    if pixels not in PIXEL_PITCH_UM:
        raise ValueError(f"pixels must be one of {sorted(PIXEL_PITCH_UM)}, got {pixels}")
    if not 8 <= bit_depth <= 16:
        raise ValueError(f"bit depth must be 8-16, got {bit_depth}")
    rng = np.random.default_rng([seed, 0x216])
    outer = rng.uniform(450.0, 800.0)
    xs = np.linspace(-outer, outer, cameras) + rng.uniform(-30.0, 30.0, cameras)
    max_dn = (1 << bit_depth) - 1
    table: dict[str, Any] = {
        "name": name or f"generated-{cameras}x{pixels}-{seed}",
        "roof_height_mm": float(roof_height_mm),
        "sensor_height_mm": float(sensor_height_mm),
        "sensor_baseline_mm": float(sensor_baseline_mm),
        "lighting": {
            "kind": "blue_strobe_bandpass",
            "lamp_x_mm": [-450.0, 0.0, 450.0],
            "lamp_z_mm": [60.0, 60.0, 60.0],
            "lamp_aim_deg": [10.0, 0.0, -10.0],
            "beam_sigma_deg": 30.0,
        },
        "cameras": [],
    }
    for number, x in enumerate(xs.tolist(), start=1):
        z = float(rng.uniform(70.0, 150.0))
        low, high = _corner_angles_deg(x, z, field_half_width_mm, field_z_mm)
        tilt = 0.5 * (low + high)
        half_field = math.radians(0.5 * (high - low) + margin_deg)
        pitch = float(rng.choice(PIXEL_PITCH_UM[pixels]))
        focal_px = 0.5 * pixels / math.tan(half_field)
        focal_mm = focal_px * pitch * 1e-3
        near, far = _depths_mm(x, z, tilt, field_half_width_mm, field_z_mm)
        focus = 2.0 * near * far / (near + far)
        # thin-lens defocus at either end (SimCamera.defocus_diameter_px), over the f-number
        blur_px_f1 = focal_mm**2 * (focus - near) / (near * (focus - focal_mm)) / (pitch * 1e-3)
        f_number = next((n for n in F_NUMBERS if blur_px_f1 / n <= max_defocus_px), F_NUMBERS[-1])
        table["cameras"].append(
            {
                "name": f"cam{number}",
                "pixels": pixels,
                "pixel_pitch_um": pitch,
                "focal_length_mm": round(focal_mm, 3),
                "x_mm": round(x, 1),
                "z_mm": round(z, 1),
                "tilt_deg": round(tilt, 3),
                "k1": round(float(rng.uniform(-0.02, 0.0)), 4),
                "f_number": f_number,
                "focus_distance_mm": round(focus, 1),
                "bit_depth": bit_depth,
                "read_noise_e": READ_NOISE_E,
                "full_well_e": FULL_WELL_E,
                "gain_dn_per_e": max_dn / FULL_WELL_E * max(f_number / 8.0, 1.0) ** 2,
                "exposure": min(f_number / 8.0, 1.0) ** 2,
                "black_level_dn": 2.0 * (max_dn + 1) / 256.0,
                "principal_point_px": round(
                    (pixels - 1) / 2.0 + rng.uniform(-0.002, 0.002) * pixels, 2
                ),
            }
        )
    text = tomli_w.dumps(table)
    return parse_rig(table, f"<generated rig, seed {seed}>", text=text)
