"""Light: lamps, surfaces, sky and sun, in electrons a camera collects.

Units. Every radiance here is expressed as the electrons one pixel of a camera at f/8 on its
optical axis collects in one exposure (``e-``); the camera's own aperture and relative
illumination scale it afterwards (:mod:`.optics`). The constants are chosen so that the
simulated lines show the contrasts the paper describes (section 2 and figures 2, 5, 7, 12), not
measured on real hardware:

- the worn flat face of a contact wire is polished by the pantographs, with scratches along
  the wire: it scatters the lamps' light into a broad lobe across the wire (in the scanning
  plane) and is several times brighter than the wire's oxidised round sides, whose brightness
  follows the surface normal (Lambert) and falls off toward the silhouette (figures 2 and 7);
- at night the sky is black and only lamp-lit surfaces show;
- by day with the blue stroboscopic lamps behind narrow band-pass filters the sky is dim
  (about 6 % of its white-light level) and the faces stay bright; the stranded messenger wire
  is about as bright as the sky and nearly disappears (figure 12b);
- by day with white lamps the sky is bright, wires are dark silhouettes, and the worn face is
  still brighter than the wire's sides (figure 12a, "black object against a bright
  background").

The lamps are point sources on the roof with a bell-shaped beam; irradiance falls with the square
of the distance, so a wire at 2500 mm is about a third as bright as at 1300 mm.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from catenary.arrays import FloatArray

from .rig import Lamp

__all__ = [
    "CONDITIONS",
    "MATERIALS",
    "Conditions",
    "Material",
    "Sky",
    "conditions_for",
    "sun_glare_e",
    "surface_radiance_e",
]

CONDITIONS = ("night", "day-filter", "day-white")
"""Lighting conditions of a run: the rig's own lamps at night, and by day the blue strobe with
band-pass filters or white lamps."""


@dataclass(frozen=True)
class Material:
    """Reflectance of a surface: a diffuse (Lambert) part and a glossy lobe in the plane.

    ``diffuse`` is the Lambert albedo; ``gloss`` the peak of a lobe around the mirror
    direction, ``exp((cos δ - 1) / σ²)`` with ``σ = gloss_sigma_deg`` (a von Mises-Fisher lobe:
    a Gaussian of width σ in the angle δ for small angles), relative to a white Lambert
    surface.
    """

    diffuse: float
    gloss: float
    gloss_sigma_deg: float


MATERIALS: dict[str, Material] = {
    # polished by the pantograph strips, scratched along the wire: broad across-wire lobe
    "worn_face": Material(diffuse=0.40, gloss=1.5, gloss_sigma_deg=22.0),
    # oxidised copper alloy of the wire's round sides: dark, a little gloss
    "wire_side": Material(diffuse=0.12, gloss=0.12, gloss_sigma_deg=25.0),
    # stranded bronze messenger wire: matt
    "messenger": Material(diffuse=0.22, gloss=0.04, gloss_sigma_deg=35.0),
    "dropper": Material(diffuse=0.22, gloss=0.05, gloss_sigma_deg=35.0),
    "clamp": Material(diffuse=0.35, gloss=0.25, gloss_sigma_deg=25.0),
    "arm": Material(diffuse=0.45, gloss=0.25, gloss_sigma_deg=25.0),
    "tube": Material(diffuse=0.40, gloss=0.20, gloss_sigma_deg=25.0),
    # the calibration tool: machined bright faces on dark targets on a black bar
    "target_face": Material(diffuse=0.40, gloss=1.5, gloss_sigma_deg=22.0),
    "target_side": Material(diffuse=0.10, gloss=0.10, gloss_sigma_deg=25.0),
    "black_bar": Material(diffuse=0.03, gloss=0.02, gloss_sigma_deg=30.0),
}

# Per lamp kind: electrons (f/8, on axis) from a white Lambert surface 1 m in front of one
# lamp on its beam axis; fraction of the white-light sky the camera's filter passes; the
# wavelength for diffraction [nm].
_LAMPS: dict[str, tuple[float, float, float]] = {
    "blue_strobe_bandpass": (6500.0, 0.06, 465.0),
    "white_led": (1800.0, 1.0, 550.0),
}
_DAY_SKY_E = 12000.0  # white-light overcast sky at the zenith, f/8
_NIGHT_SKY_E = 25.0  # night sky glow (towns, clouds lit from below), white light
_AMBIENT_FRACTION = 0.3  # by day: irradiance on the wires' undersides over the sky's


@dataclass(frozen=True)
class Conditions:
    """The light of a run: lamp kind and strength, sky level, ambient light on surfaces."""

    name: str
    lamp_kind: str
    lamp_e: float
    sky_e: float
    ambient_e: float
    cloud_amplitude: float
    wavelength_nm: float

    @property
    def daylight(self) -> bool:
        return self.name != "night"


def conditions_for(name: str, rig_lamp_kind: str) -> Conditions:
    """The :class:`Conditions` for ``night``, ``day-filter`` or ``day-white``.

    At night the rig's own lamps are used; ``day-filter`` is the blue strobe with band-pass
    filters and ``day-white`` white lamps, whatever the rig carries.
    """
    if name not in CONDITIONS:
        raise ValueError(f"lighting must be one of {', '.join(CONDITIONS)}, got {name!r}")
    kind = {"night": rig_lamp_kind, "day-filter": "blue_strobe_bandpass", "day-white": "white_led"}[
        name
    ]
    lamp_e, transmission, wavelength = _LAMPS[kind]
    if name == "night":
        sky = _NIGHT_SKY_E * transmission
        return Conditions(name, kind, lamp_e, sky, 0.0, 0.05, wavelength)
    sky = _DAY_SKY_E * transmission
    return Conditions(name, kind, lamp_e, sky, _AMBIENT_FRACTION * sky, 0.15, wavelength)


def surface_radiance_e(
    point: FloatArray,
    normal: FloatArray,
    view: FloatArray,
    material: Material,
    lamps: tuple[Lamp, ...],
    lamp_e: float,
    beam_sigma_deg: float,
    ambient_e: float,
) -> FloatArray:
    """Radiance of lit surface points toward the camera [e-, f/8 on axis].

    Parameters
    ----------
    point : ndarray, shape (..., 2)
        Roof-frame surface points [mm].
    normal : ndarray, shape (..., 2)
        In-plane outward normals (length <= 1: the in-plane part of the surface normal).
    view : ndarray, shape (..., 2)
        Unit vectors from the points toward the camera.
    material : Material
    lamps : tuple of Lamp
        Roof-mounted point lamps; beam profile ``exp((cos α - 1) / σ²)`` at the angle α from
        a lamp's axis, ``σ = beam_sigma_deg`` (Gaussian in α for small angles).
    lamp_e : float
        Electrons from a white Lambert surface 1 m from one lamp on its axis [e-].
    ambient_e : float
        Ambient (daylight) radiance of a white Lambert surface [e-].

    Returns
    -------
    ndarray, shape (...)
        ``Σ_lamps lamp_e · beam · (ρd cos i + ρg · lobe · cos i) / d²[m] + ambient``.
    """
    total = np.zeros(point.shape[:-1], dtype=np.float64)
    nx = normal[..., 0]
    nz = normal[..., 1]
    norm = np.maximum(np.hypot(nx, nz), 1e-12)
    ux, uz = nx / norm, nz / norm  # unit in-plane normal for the mirror direction
    sigma_beam = math.radians(beam_sigma_deg)
    sigma_gloss = math.radians(material.gloss_sigma_deg)
    for lamp in lamps:
        lx = lamp.x_mm - point[..., 0]
        lz = lamp.z_mm - point[..., 1]
        dist2 = lx * lx + lz * lz
        dist = np.sqrt(dist2)
        lx /= dist
        lz /= dist
        cos_i = np.maximum(nx * lx + nz * lz, 0.0)
        # beam: cosine of the angle between the lamp's axis and the direction lamp -> point
        aim = math.radians(lamp.aim_deg)
        cos_beam = -(lx * math.sin(aim) + lz * math.cos(aim))
        beam = np.exp((cos_beam - 1.0) / sigma_beam**2)
        reflect = material.diffuse * cos_i
        if material.gloss > 0.0:
            cos_unit = ux * lx + uz * lz
            rx = 2.0 * cos_unit * ux - lx
            rz = 2.0 * cos_unit * uz - lz
            cos_delta = rx * view[..., 0] + rz * view[..., 1]
            lobe = np.exp((cos_delta - 1.0) / sigma_gloss**2)
            reflect = reflect + material.gloss * lobe * cos_i
        total += lamp_e * beam * reflect / (dist2 * 1e-6)
    if ambient_e > 0.0:
        total += ambient_e * (material.diffuse + 0.5 * material.gloss) * np.minimum(norm, 1.0)
    return total


@dataclass(frozen=True)
class Sky:
    """The sky behind the wires: an overcast gradient with drifting clouds [e-, f/8].

    The cloud pattern is a smooth random field over the lateral position at the cloud base
    (``cloud_height_m · tan ζ`` for a ray at zenith angle ``ζ``) and the distance travelled,
    so it moves across the line as the train runs under it. Brightness ``level_e ·
    (1 + 2 cos ζ) / 3 · exp(amplitude · F)`` (the CIE overcast sky's gradient) with ``F`` of
    unit variance.
    """

    level_e: float
    cloud_amplitude: float
    wave_x_per_m: FloatArray
    wave_s_per_m: FloatArray
    phase: FloatArray
    weight: FloatArray
    cloud_height_m: float = 1500.0

    @classmethod
    def random(cls, level_e: float, cloud_amplitude: float, rng: np.random.Generator) -> Sky:
        """A sky with eight cloud components of wavelengths 150-900 m."""
        count = 8
        wavelength = rng.uniform(150.0, 900.0, count)
        direction = rng.uniform(0.0, 2.0 * math.pi, count)
        weight = rng.uniform(0.5, 1.0, count)
        weight /= np.sqrt(np.sum(weight**2) / 2.0)  # unit variance of Σ w cos(...)
        return cls(
            level_e=level_e,
            cloud_amplitude=cloud_amplitude,
            wave_x_per_m=np.cos(direction) / wavelength,
            wave_s_per_m=np.sin(direction) / wavelength,
            phase=rng.uniform(0.0, 2.0 * math.pi, count),
            weight=weight,
        )

    def radiance_e(self, zenith_rad: FloatArray, distance_m: FloatArray) -> FloatArray:
        """Sky radiance ``[n, K]`` for rays at signed zenith angles ``[K]``, scans at ``[n]``."""
        zen = np.clip(zenith_rad, -1.45, 1.45)
        lateral_m = self.cloud_height_m * np.tan(zen)
        phase = (
            2.0
            * math.pi
            * (
                lateral_m[None, :, None] * self.wave_x_per_m
                + distance_m[:, None, None] * self.wave_s_per_m
            )
            + self.phase
        )
        field = np.sum(self.weight * np.cos(phase), axis=-1)
        gradient = (1.0 + 2.0 * np.cos(zen)) / 3.0
        return np.asarray(
            self.level_e * gradient[None, :] * np.exp(self.cloud_amplitude * field),
            dtype=np.float64,
        )


def sun_glare_e(
    ray_angle_rad: FloatArray, sun_angle_rad: float, strength: FloatArray, full_well_e: float
) -> FloatArray:
    """Electrons of sun glare ``[n, W]``: the sun's halo plus veiling glare in the lens.

    ``strength`` ``[n]`` (0-1) ramps the glare in and out; at full strength every pixel gets
    more than its full well (a sun-blinded camera saturates across the line).
    """
    halo = 40.0 * np.exp(-0.5 * ((ray_angle_rad - sun_angle_rad) / math.radians(8.0)) ** 2)
    return np.asarray(full_well_e * strength[:, None] * (1.6 + halo[None, :]), dtype=np.float64)
