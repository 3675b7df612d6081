"""A section of overhead line laid out from parameters and a seed: masts, wires and fittings.

Coordinates are the **line frame**: chainage ``c`` [m] along the track; lateral offset ``y``
[mm] from the track centre line, positive to the right looking toward increasing chainage;
height ``h`` [mm] above top of rail, perpendicular to the track. A run in the ``decreasing``
direction sees ``x = -y`` in its track frame (FORMATS.md).

What is generated (the figures in ``reference/wire-profiles.md``):

- **Masts** every 40-65 m (shorter in curves, so that the wire stays within its stagger
  limits mid-span); each registers the contact wire with a steady arm. Mast codes are
  ``"<km>/<n>"``.
- **Stagger**: on straight track a zigzag of ±200-400 mm between consecutive registration
  points; in curves every registration is on the outside of the curve and the wire, a straight
  chord between registration points, swings inward mid-span by the versine ``c(L - c)/(2R)``
  of the curved track ("offset arcs"). The stagger gradient along the track gives the angle
  ``θ`` at which the scanning plane cuts the wire (``tan θ = dy/dc``, the paper's eq. 11-12).
- **Heights**: contact wire heights at the registration points 1300-2500 mm above the roof
  (nominal ride), changing slowly from mast to mast; between them the wire follows its
  pre-sag (0-1/1000 of the span, lowest mid-span) and sags a few millimetres between its
  hanging points (``m g L² / (8 T)`` with the wire's mass and tension).
- **Messenger wire** above each contact wire (same stagger: a vertical catenary), 1100-1800 mm
  above it at the supports, sagging mid-span by ``m g L² / (8 T)`` with the load of both wires
  (never leaving less than 400 mm of dropper).
- **Droppers** every 5-10 m, vertical from the contact wire's top to the messenger's bottom,
  with a clamp on the contact wire; **steady arms** (registration arms) at each registration
  point: a tube from the wire's top toward the mast side rising 8°, a registration clamp on
  the wire, and the cantilever's registration tube above.
- **Overlap** (optional): two spans where a second contact wire (with its messenger) runs
  alongside: the ending wire rises out of contact (300-500 mm at the next mast, then to its
  anchor) and moves to the mast side; the new wire comes down from its anchor; at the middle
  mast both are at running height 200 mm apart.
- **Wear**: the flat face width ``w0`` (perpendicular to the wire) varies smoothly along each
  contact wire (a base level plus random undulation), with hot spots at registration points
  (stronger in curves) and at the overlap's transfer point, 0-12 mm; wires raised out of
  contact are not worn.

Simplifications: curvature is constant per span (curves begin and end at masts, no
transition spirals); cant is not modelled (the track frame follows the rails); the
messenger's sag is a parabola (not a polygon of dropper loads); masts themselves are outside
the cameras' fields and are not drawn.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from catenary.arrays import BoolArray, FloatArray, IndexArray
from catenary.errors import UserError

__all__ = [
    "Fittings",
    "Mast",
    "Scene",
    "SceneParams",
    "WireProfile",
    "WireSamples",
    "WireTypeDims",
    "generate_scene",
    "wire_type_dims",
]

GRAVITY = 9.81
COPPER_DENSITY_KG_PER_MM2_M = 8.9e-3  # kg per metre per mm² of cross-section
MESSENGER_DIAMETER_MM = 14.0  # 120 mm² bronze stranded messenger
MESSENGER_MASS_KG_PER_M = 1.07
DROPPER_RADIUS_MM = 2.5
ARM_RADIUS_MM = 13.0
ARM_LENGTH_MM = 1100.0
ARM_SLOPE_DEG = 8.0
TUBE_RADIUS_MM = 21.0
MIN_DROPPER_MM = 400.0
OVERLAP_SEPARATION_MM = 200.0


@dataclass(frozen=True)
class WireTypeDims:
    """A contact wire profile's nominal geometry: ``A`` height, ``B`` width [mm], area [mm²]."""

    name: str
    height_mm: float
    width_mm: float
    area_mm2: float

    @property
    def radius_mm(self) -> float:
        return self.width_mm / 2.0

    @property
    def max_wear_mm(self) -> float:
        """The widest face the generator gives this profile: 12 mm, or 93 % of its width."""
        return min(12.0, 0.93 * self.width_mm)


def wire_type_dims(name: str) -> WireTypeDims:
    """The geometry of wire type ``name`` from the built-in wire types plugin.

    Falls back to CTA120 (A = B = 12.90 mm, 121 mm²) when the plugin is not importable;
    ``UserError`` for an unknown name.
    """
    try:
        from catenary_wiretypes import load_profiles
    except ImportError:  # pragma: no cover - the plugin ships with catenary
        profiles = []
    else:
        profiles = load_profiles()
    for profile in profiles:
        if profile.name == name:
            return WireTypeDims(name, profile.height_mm, profile.width_mm, profile.area_mm2)
    if name == "CTA120":
        return WireTypeDims("CTA120", 12.90, 12.90, 121.0)
    known = ", ".join(p.name for p in profiles) or "CTA120"
    raise UserError(f"unknown wire type {name!r} (known: {known})")


@dataclass(frozen=True)
class SceneParams:
    """What the generator lays out (lengths in the unit their name says).

    ``curve_radius_m``: None lets the seed decide (about half of the sections longer than
    200 m get a curve over their second half), 0 keeps the section straight, a positive value
    puts a curve of that radius over the second half (sign of ``curve_direction``: +1 bends
    to the right). ``contact_height_above_roof_mm`` bounds the heights at registration points
    (track frame minus ``roof_height_mm``). ``start_chainage_m`` is the lower end of the
    run's chainages, whichever way the train runs.
    """

    length_m: float = 300.0
    start_chainage_m: float = 12000.0
    margin_m: float = 150.0
    line: str = "demo-line"
    track: str = "1"
    wire_type: str = "CTA120"
    overlap: bool = True
    curve_radius_m: float | None = None
    curve_direction: int = 0  # 0: seed decides
    roof_height_mm: float = 3900.0
    contact_height_above_roof_mm: tuple[float, float] = (1300.0, 2500.0)
    span_m: tuple[float, float] = (40.0, 65.0)
    stagger_mm: tuple[float, float] = (200.0, 400.0)
    curve_stagger_mm: tuple[float, float] = (150.0, 300.0)
    system_height_mm: tuple[float, float] = (1100.0, 1800.0)
    dropper_spacing_m: tuple[float, float] = (5.0, 10.0)
    wear_base_mm: tuple[float, float] = (1.5, 8.0)


@dataclass(frozen=True)
class Mast:
    """One mast of the register (FORMATS.md mast register)."""

    code: str
    chainage_m: float
    side: int  # +1: right of the track looking toward increasing chainage, -1: left
    design_stagger_mm: float
    wire_type: str


@dataclass(frozen=True)
class WireProfile:
    """One wire (contact or messenger) as its support points and per-span shape.

    ``stagger``, ``height`` and ``lift`` are given at the supports ``[k]`` and interpolated
    linearly; per span ``[k-1]`` the height sags by ``sag_mm`` (parabola, lowest mid-span) and
    the stagger bows by the track's versine with ``curvature_per_m`` (+: bending right).
    ``hanging_m`` are the points the wire hangs from within its spans (droppers, for a contact
    wire); between them it sags by ``scallop_per_m2 · L²`` more.
    """

    id: int
    name: str
    contact: bool
    partner: int  # the messenger of a contact wire, the contact wire of a messenger
    support_m: FloatArray
    stagger_mm: FloatArray
    height_mm: FloatArray
    lift_mm: FloatArray
    registered: BoolArray
    sag_mm: FloatArray
    curvature_per_m: FloatArray
    hanging_m: FloatArray
    scallop_per_m2: float
    radius_mm: float
    wear_base_mm: float = 0.0
    wear_waves: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # amp, λ m, phase
    wear_spots: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))  # c m, amp, σ m
    max_wear_mm: float = 12.0

    @property
    def start_m(self) -> float:
        return float(self.support_m[0])

    @property
    def end_m(self) -> float:
        return float(self.support_m[-1])

    def evaluate(self, chainage_m: FloatArray) -> tuple[FloatArray, ...]:
        """``(present, stagger_mm, height_mm, slope_mm_per_m, lift_mm)`` at ``[n]`` chainages.

        ``height_mm`` is the wire's lowest point (the contact point of a contact wire, the
        underside of a messenger); ``slope`` the stagger gradient ``dy/dc``.
        """
        c = np.asarray(chainage_m, dtype=np.float64)
        support = self.support_m
        present = (c >= support[0]) & (c <= support[-1])
        k = np.clip(np.searchsorted(support, c, side="right") - 1, 0, support.shape[0] - 2)
        c0 = support[k]
        span = support[k + 1] - c0
        s = c - c0
        t = s / span
        y0, y1 = self.stagger_mm[k], self.stagger_mm[k + 1]
        kappa = self.curvature_per_m[k]
        stagger = y0 + (y1 - y0) * t + 1000.0 * kappa * s * (span - s) / 2.0
        slope = (y1 - y0) / span + 1000.0 * kappa * (span - 2.0 * s) / 2.0
        h0, h1 = self.height_mm[k], self.height_mm[k + 1]
        height = h0 + (h1 - h0) * t - self.sag_mm[k] * 4.0 * t * (1.0 - t)
        if self.hanging_m.shape[0] and self.scallop_per_m2 > 0.0:
            points = self.hanging_m
            j = np.clip(np.searchsorted(points, c, side="right") - 1, 0, points.shape[0] - 2)
            length = points[j + 1] - points[j]
            tau = np.clip((c - points[j]) / length, 0.0, 1.0)
            height = height - self.scallop_per_m2 * length**2 * 4.0 * tau * (1.0 - tau)
        lift = self.lift_mm[k] + (self.lift_mm[k + 1] - self.lift_mm[k]) * t
        return present, stagger, height, slope, lift

    def wear_mm(self, chainage_m: FloatArray, lift_mm: FloatArray) -> FloatArray:
        """Flat face width ``w0`` [mm] perpendicular to the wire at ``[n]`` chainages."""
        c = np.asarray(chainage_m, dtype=np.float64)
        if not self.contact:
            return np.zeros_like(c)
        wear = np.full_like(c, self.wear_base_mm)
        for amp, wavelength, phase in self.wear_waves:
            wear += amp * np.sin(2.0 * math.pi * c / wavelength + phase)
        for centre, amp, sigma in self.wear_spots:
            wear += amp * np.exp(-0.5 * ((c - centre) / sigma) ** 2)
        # raised out of contact: no wear beyond 60 mm of lift, a smooth ramp from 10 mm
        ramp = np.clip((lift_mm - 10.0) / 50.0, 0.0, 1.0)
        fade = 0.5 * (1.0 + np.cos(math.pi * ramp))
        return np.clip(wear, 0.0, self.max_wear_mm) * fade


@dataclass(frozen=True)
class WireSamples:
    """The scene's wires at ``n`` chainages: every field ``[n, M]`` for ``M`` wires."""

    present: BoolArray
    stagger_mm: FloatArray
    height_mm: FloatArray
    slope_mm_per_m: FloatArray
    lift_mm: FloatArray
    wear_width_mm: FloatArray


@dataclass(frozen=True)
class Fittings:
    """Small objects along the line, each cut by few scans: arrays ``[F]`` sorted by chainage.

    Each is a bar in the line frame's ``y``-``h`` plane: centre ``(y_mm, h_mm)``, half sizes,
    angle (counter-clockwise in ``y``-``h``), present in scans within ``reach_mm`` of its
    chainage. ``curved`` says which of its faces belong to a cylinder cut off-axis: 1 the faces
    across ``y`` (a vertical rod: its width shrinks off-axis), 2 the faces across ``h`` (a
    horizontal tube across the track), 0 none (a block).
    """

    kind: NDArray[np.str_]
    wire: IndexArray
    chainage_m: FloatArray
    y_mm: FloatArray
    h_mm: FloatArray
    half_width_mm: FloatArray
    half_height_mm: FloatArray
    angle_rad: FloatArray
    reach_mm: FloatArray
    curved: IndexArray

    @property
    def count(self) -> int:
        return int(self.chainage_m.shape[0])

    def near(self, low_m: float, high_m: float) -> IndexArray:
        """Indices of fittings that any scan in ``[low_m, high_m]`` may cut."""
        reach = float(np.max(self.reach_mm, initial=0.0)) / 1000.0
        first = int(np.searchsorted(self.chainage_m, low_m - reach, side="left"))
        last = int(np.searchsorted(self.chainage_m, high_m + reach, side="right"))
        return np.arange(first, last, dtype=np.intp)


@dataclass(frozen=True)
class Scene:
    """A generated section of line (module docstring)."""

    params: SceneParams
    seed: int
    wire_type: WireTypeDims
    start_m: float
    end_m: float
    masts: tuple[Mast, ...]
    wires: tuple[WireProfile, ...]
    fittings: Fittings
    curve_start_m: float
    curve_end_m: float
    curvature_per_m: float  # of the curve (+: bending right); 0 when straight
    overlap_masts: tuple[int, ...]  # indices into masts: the overlap's three masts

    @property
    def contact_ids(self) -> list[int]:
        return [w.id for w in self.wires if w.contact]

    def with_constant_wear(self, wear_mm: float) -> Scene:
        """The same scene with every contact wire's face ``wear_mm`` wide [mm] throughout (no
        undulation, no hot spots; 0: new wires)."""
        wires = tuple(
            replace(
                w,
                wear_base_mm=float(wear_mm),
                wear_waves=np.zeros((0, 3)),
                wear_spots=np.zeros((0, 3)),
                max_wear_mm=max(w.max_wear_mm, float(wear_mm)),
            )
            if w.contact
            else w
            for w in self.wires
        )
        return replace(self, wires=wires)

    def curvature_at(self, chainage_m: FloatArray) -> FloatArray:
        """Track curvature [1/m] (+: bending right) at ``[n]`` chainages."""
        c = np.asarray(chainage_m, dtype=np.float64)
        inside = (c >= self.curve_start_m) & (c < self.curve_end_m)
        return np.where(inside, self.curvature_per_m, 0.0)

    def sample(self, chainage_m: FloatArray) -> WireSamples:
        """Every wire at ``[n]`` chainages (:class:`WireSamples`)."""
        c = np.asarray(chainage_m, dtype=np.float64)
        columns = []
        for wire in self.wires:
            present, stagger, height, slope, lift = wire.evaluate(c)
            wear = wire.wear_mm(c, lift)
            columns.append((present, stagger, height, slope, lift, wear))
        stacked = [np.stack(parts, axis=1) for parts in zip(*columns, strict=True)]
        return WireSamples(*stacked)


# -- generation ----------------------------------------------------------------------------


def _mast_codes(chainages: FloatArray) -> list[str]:
    codes = []
    count: dict[int, int] = {}
    for c in chainages:
        km = math.floor(c / 1000.0)
        count[km] = count.get(km, 0) + 1
        codes.append(f"{km}/{count[km]:02d}")
    return codes


def _hanging_points(
    support: FloatArray, spacing: tuple[float, float], rng: np.random.Generator
) -> FloatArray:
    """Dropper chainages in every span: 4-5 m from the supports, 5-10 m apart."""
    points = []
    for c0, c1 in itertools.pairwise(support):
        length = c1 - c0
        end = rng.uniform(4.0, 5.0)
        inner = length - 2.0 * end
        if inner <= spacing[0] * 0.5:
            points.append(np.array([0.5 * (c0 + c1)]))
            continue
        count = max(2, math.ceil(inner / spacing[1]) + 1)
        points.append(np.linspace(c0 + end, c1 - end, count))
    return np.concatenate(points) if points else np.zeros(0)


def generate_scene(params: SceneParams, seed: int) -> Scene:
    """Lay out a section of line covering the run plus ``margin_m`` on each side."""
    if params.length_m <= 0:
        raise UserError(f"section length must be positive, got {params.length_m} m")
    rng = np.random.default_rng([seed, 0x5CE7E])
    dims = wire_type_dims(params.wire_type)
    run_start = params.start_chainage_m
    start = run_start - params.margin_m
    end = run_start + params.length_m + params.margin_m
    lo_h, hi_h = params.contact_height_above_roof_mm
    if not 800.0 <= lo_h < hi_h:
        raise UserError(f"contact wire heights above the roof must rise, got {lo_h}-{hi_h} mm")

    # the curve: over the run's second half, to the scene's end
    radius = params.curve_radius_m
    if radius is None:
        radius = rng.uniform(700.0, 2500.0) if params.length_m >= 200 and rng.random() < 0.5 else 0
    direction = params.curve_direction or int(rng.choice([-1, 1]))
    curvature = direction / radius if radius else 0.0
    curve_from = run_start + 0.55 * params.length_m if radius else math.inf

    # masts and spans
    masts_c = [start + rng.uniform(0.0, 20.0) - 20.0]
    curved_span: list[bool] = []
    while masts_c[-1] < end + 1.0:
        c = masts_c[-1]
        length = rng.uniform(*params.span_m)
        in_curve = radius and c >= curve_from - 1e-9
        if in_curve:
            inside_mm = 200.0
            limit = math.sqrt(8.0 * radius * (params.curve_stagger_mm[1] + inside_mm) / 1000.0)
            length = min(length, max(limit, 30.0))
        elif radius and c + length > curve_from:
            length = max(curve_from - c, 30.0) if curve_from - c > 30.0 else length
        masts_c.append(c + length)
        curved_span.append(bool(in_curve))
    support = np.array(masts_c)
    spans = np.diff(support)
    curve_start = float(support[:-1][np.array(curved_span)][0]) if any(curved_span) else math.inf
    curve_end = float(support[-1]) if any(curved_span) else math.inf
    kappa = np.where(np.array(curved_span), curvature, 0.0)
    n_masts = support.shape[0]
    mast_in_curve = np.zeros(n_masts, dtype=bool)
    mast_in_curve[1:] |= np.array(curved_span)
    mast_in_curve[:-1] |= np.array(curved_span)

    # stagger at the registration points
    side_straight = int(rng.choice([-1, 1]))
    stagger = np.empty(n_masts)
    sign = int(rng.choice([-1, 1]))
    for i in range(n_masts):
        if mast_in_curve[i]:
            stagger[i] = -direction * rng.uniform(*params.curve_stagger_mm)
        else:
            stagger[i] = sign * rng.uniform(*params.stagger_mm)
            sign = -sign
    mast_side = np.where(mast_in_curve, -direction, side_straight).astype(int)

    # heights at the registration points (track frame), slowly changing
    roof = params.roof_height_mm
    above = np.empty(n_masts)
    above[0] = rng.uniform(lo_h + 150.0, min(hi_h - 250.0, lo_h + 900.0))
    for i in range(1, n_masts):
        step = rng.normal(0.0, 40.0)
        if rng.random() < 0.15:
            step += rng.choice([-1, 1]) * rng.uniform(1.0, 2.5) * spans[i - 1]  # up to 2.5 ‰
        above[i] = np.clip(above[i - 1] + step, lo_h + 80.0, hi_h - 120.0)
    height = roof + above
    presag = rng.uniform(0.0, 1.0, n_masts - 1) * spans  # 0-1/1000 of the span, mm
    system = np.full(n_masts, rng.uniform(*params.system_height_mm))
    system += rng.normal(0.0, 20.0, n_masts)
    system = np.clip(system, *params.system_height_mm)
    contact_mass = dims.area_mm2 * COPPER_DENSITY_KG_PER_MM2_M
    contact_tension = rng.uniform(15000.0, 30000.0)
    messenger_tension = rng.uniform(14000.0, 21000.0)
    scallop = 1000.0 * GRAVITY * contact_mass / (8.0 * contact_tension)  # mm per m²
    load = GRAVITY * (contact_mass + MESSENGER_MASS_KG_PER_M + 0.1)
    messenger_sag = 1000.0 * load * spans**2 / (8.0 * messenger_tension)

    # wires: supports, lifts and staggers (an overlap splits the line into two wires)
    overlap_masts: tuple[int, ...] = ()
    wire_ranges: list[tuple[int, int]] = [(0, n_masts - 1)]
    lift = [np.zeros(n_masts)]
    staggers = [stagger.copy()]
    anchors: list[set[int]] = [set()]
    if params.overlap:
        middle = run_start + 0.5 * params.length_m
        j1 = int(np.argmin(np.abs(support - middle)))
        j1 = min(max(j1, 2), n_masts - 4)
        if j1 < 2 or j1 + 3 > n_masts - 1:
            raise UserError("the section is too short for an overlap: make it longer")
        j0, j2 = j1 - 1, j1 + 1
        overlap_masts = (j0, j1, j2)
        m = int(mast_side[j1])
        # both wires run at the middle mast: keep them within ±400 mm
        stagger[j1] = np.clip(stagger[j1], -250.0, 250.0)
        lift_a = np.zeros(n_masts)
        lift_b = np.zeros(n_masts)
        stagger_a = stagger.copy()
        stagger_b = stagger.copy()
        stagger_a[j1] = stagger[j1] - m * OVERLAP_SEPARATION_MM / 2.0
        stagger_b[j1] = stagger[j1] + m * OVERLAP_SEPARATION_MM / 2.0
        lift_a[j2] = rng.uniform(300.0, 500.0)
        stagger_a[j2] = stagger[j2] + m * rng.uniform(200.0, 300.0)
        lift_a[j2 + 1] = 1500.0
        stagger_a[j2 + 1] = m * 2800.0
        lift_b[j0] = rng.uniform(300.0, 500.0)
        stagger_b[j0] = stagger[j0] + m * rng.uniform(200.0, 300.0)
        lift_b[j0 - 1] = 1500.0
        stagger_b[j0 - 1] = m * 2800.0
        wire_ranges = [(0, j2 + 1), (j0 - 1, n_masts - 1)]
        lift = [lift_a, lift_b]
        staggers = [stagger_a, stagger_b]
        anchors = [{j2 + 1}, {j0 - 1}]

    masts = tuple(
        Mast(code, float(c), int(side), float(round(s, 1)), dims.name)
        for code, c, side, s in zip(_mast_codes(support), support, mast_side, stagger, strict=True)
    )
    if overlap_masts:
        j0, j1, j2 = overlap_masts
        replaced = list(masts)
        for j, value in ((j1, staggers[0][j1]), (j2, staggers[1][j2])):
            replaced[j] = Mast(
                masts[j].code, masts[j].chainage_m, masts[j].side, float(round(value, 1)), dims.name
            )
        masts = tuple(replaced)

    wires: list[WireProfile] = []
    kinds: list[str] = []
    f_wire: list[int] = []
    f_c: list[float] = []
    f_y: list[float] = []
    f_h: list[float] = []
    f_hw: list[float] = []
    f_hh: list[float] = []
    f_angle: list[float] = []
    f_reach: list[float] = []
    f_curved: list[int] = []

    def add(
        kind: str,
        wire: int,
        c: float,
        y: float,
        h: float,
        hw: float,
        hh: float,
        angle: float,
        reach: float,
        curved: int,
    ) -> None:
        kinds.append(kind)
        f_wire.append(wire)
        f_c.append(c)
        f_y.append(y)
        f_h.append(h)
        f_hw.append(hw)
        f_hh.append(hh)
        f_angle.append(angle)
        f_reach.append(reach)
        f_curved.append(curved)

    for number, ((first, last), wire_lift, wire_stagger, anchor) in enumerate(
        zip(wire_ranges, lift, staggers, anchors, strict=True)
    ):
        idx = np.arange(first, last + 1)
        wire_support = support[idx]
        registered = np.array([i not in anchor for i in idx])
        contact_height = height[idx] + wire_lift[idx]
        hanging = _hanging_points(wire_support, params.dropper_spacing_m, rng)
        contact_id = 2 * number
        letter = "AB"[number] if len(wire_ranges) > 1 else "A"
        # wear: base, undulation and hot spots where the wire runs
        waves = np.stack(
            [
                rng.uniform(0.1, 0.35, 5),
                rng.uniform(4.0, 80.0, 5),
                rng.uniform(0.0, 2.0 * math.pi, 5),
            ],
            axis=1,
        )
        spots = []
        for i in idx.tolist():
            if wire_lift[i] == 0.0 and i not in anchor:
                amp = rng.uniform(0.3, 2.0) * (1.6 if mast_in_curve[i] else 1.0)
                spots.append((support[i], amp, rng.uniform(1.0, 2.5)))
        if overlap_masts:
            spots.append((support[overlap_masts[1]], rng.uniform(1.5, 3.0), rng.uniform(3.0, 6.0)))
        contact = WireProfile(
            id=contact_id,
            name=f"CW-{letter}",
            contact=True,
            partner=contact_id + 1,
            support_m=wire_support,
            stagger_mm=wire_stagger[idx],
            height_mm=contact_height,
            lift_mm=wire_lift[idx],
            registered=registered,
            sag_mm=presag[idx[:-1]],
            curvature_per_m=kappa[idx[:-1]],
            hanging_m=np.sort(np.concatenate([wire_support, hanging])),
            scallop_per_m2=scallop,
            radius_mm=dims.radius_mm,
            wear_base_mm=rng.uniform(*params.wear_base_mm),
            wear_waves=waves,
            wear_spots=np.array(spots).reshape(-1, 3),
            max_wear_mm=dims.max_wear_mm,
        )
        sag = np.minimum(
            messenger_sag[idx[:-1]],
            np.minimum(system[idx[:-1]], system[idx[1:]]) + presag[idx[:-1]] - MIN_DROPPER_MM,
        )
        messenger = WireProfile(
            id=contact_id + 1,
            name=f"MW-{letter}",
            contact=False,
            partner=contact_id,
            support_m=wire_support,
            stagger_mm=wire_stagger[idx],
            height_mm=contact_height + system[idx] + dims.height_mm,
            lift_mm=np.zeros(idx.shape[0]),
            registered=registered,
            sag_mm=np.maximum(sag, 0.0),
            curvature_per_m=kappa[idx[:-1]],
            hanging_m=np.zeros(0),
            scallop_per_m2=0.0,
            radius_mm=MESSENGER_DIAMETER_MM / 2.0,
        )
        wires += [contact, messenger]

        # droppers and their clamps
        _, y_cw, h_cw, _, _ = contact.evaluate(hanging)
        _, _, h_mw, _, _ = messenger.evaluate(hanging)
        top_cw = h_cw + dims.height_mm
        for c, y, low, high in zip(hanging, y_cw, top_cw, h_mw, strict=True):
            add(
                "dropper",
                contact_id,
                c,
                y,
                0.5 * (low + high),
                DROPPER_RADIUS_MM,
                0.5 * (high - low),
                0.0,
                DROPPER_RADIUS_MM,
                1,
            )
            clamp_low = low - dims.height_mm + 0.45 * dims.height_mm
            clamp_high = low + 6.0
            add(
                "dropper_clamp",
                contact_id,
                c,
                y,
                0.5 * (clamp_low + clamp_high),
                11.0,
                0.5 * (clamp_high - clamp_low),
                0.0,
                15.0,
                0,
            )
        # steady arms, registration clamps and registration tubes
        for i, reg in zip(idx.tolist(), registered, strict=True):
            if not reg:
                continue
            side = int(mast_side[i])
            y = float(wire_stagger[i])
            h = float(contact_height[idx == i][0])
            slope = math.radians(ARM_SLOPE_DEG)
            top = h + dims.height_mm + 6.0
            half = ARM_LENGTH_MM / 2.0
            add(
                "steady_arm",
                contact_id,
                float(support[i]),
                y + side * half * math.cos(slope),
                top + ARM_RADIUS_MM + half * math.sin(slope),
                half,
                ARM_RADIUS_MM,
                side * slope,
                ARM_RADIUS_MM,
                2,
            )
            add(
                "registration_clamp",
                contact_id,
                float(support[i]),
                y,
                top + 6.0,
                20.0,
                12.0,
                0.0,
                25.0,
                0,
            )
            near, far = -350.0, 2000.0
            add(
                "registration_tube",
                contact_id,
                float(support[i]),
                y + side * 0.5 * (near + far),
                h + 320.0,
                0.5 * (far - near),
                TUBE_RADIUS_MM,
                0.0,
                TUBE_RADIUS_MM,
                2,
            )

    order = np.argsort(np.array(f_c), kind="stable")
    fittings = Fittings(
        kind=np.array(kinds)[order],
        wire=np.array(f_wire, dtype=np.intp)[order],
        chainage_m=np.array(f_c)[order],
        y_mm=np.array(f_y)[order],
        h_mm=np.array(f_h)[order],
        half_width_mm=np.array(f_hw)[order],
        half_height_mm=np.array(f_hh)[order],
        angle_rad=np.array(f_angle)[order],
        reach_mm=np.array(f_reach)[order],
        curved=np.array(f_curved, dtype=np.intp)[order],
    )
    return Scene(
        params=params,
        seed=seed,
        wire_type=dims,
        start_m=float(support[0]),
        end_m=float(support[-1]),
        masts=masts,
        wires=tuple(wires),
        fittings=fittings,
        curve_start_m=curve_start,
        curve_end_m=curve_end,
        curvature_per_m=float(curvature) if math.isfinite(curve_start) else 0.0,
        overlap_masts=overlap_masts,
    )
