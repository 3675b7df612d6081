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
  above it at the supports (``system_height_mm``: 300-1800 mm admitted), sagging mid-span by
  ``m g L² / (8 T)`` with the load of both wires, never leaving less than the shortest
  dropper: 400 mm in systems of 1100 mm and more, ``system - 700`` mm but at least 150 mm in
  lower ones (a low system cannot sag: its messenger is tensioned nearly straight).
- **Droppers** every 5-10 m, vertical from the contact wire's top to the messenger's bottom,
  with a clamp on the contact wire; **steady arms** (registration arms) at each registration
  point: a tube from the wire's top toward the mast side rising 8°, a registration clamp on
  the wire, and the cantilever's registration tube above.
- **Overlap** (optional): two spans where a second contact wire (with its messenger) runs
  alongside: the ending wire rises out of contact (300-500 mm at the next mast, then to its
  anchor) and moves to the mast side; the new wire comes down from its anchor; at the middle
  mast both are at running height 200 mm apart.
- **Turnout** (optional, ``turnout_angle_deg``; not with an overlap): a crossed arrangement
  near mid-run. The diverging track's contact wire (with its messenger and droppers, registered
  from the turnout's own masts, which are not in this track's register) is straight in plan
  and crosses the main contact wire at ``turnout_angle_deg`` in plan, at the main wire's height,
  within 250 mm of the track centre and 5 m or more from the main line's masts. It comes down
  from its anchor on the far side to running height 300-500 mm from the track centre, runs
  level with the main wire (its droppers cut for it) through the crossing and rises slowly
  beyond it (50-100 mm at 400-700 mm further across the track, then out of the cameras' view
  toward its next support), so that it is running (lift under 20 mm: the pantograph touches
  it) from where it comes down to about 80-280 mm past the crossing, always within about
  550 mm of the track centre. A cross-over pipe clamped above the main wire holds the two
  wires together at the crossing; the crossing is a wear hot spot on both wires.
- **Wear**: the flat face width ``w0`` (perpendicular to the wire) varies smoothly along each
  contact wire (a base level plus random undulation), with hot spots at registration points
  (stronger in curves) and at the overlap's transfer point, 0-12 mm; wires raised out of
  contact are not worn.

Simplifications: curvature is constant per span (curves begin and end at masts, no
transition spirals); cant is not modelled (the track frame follows the rails); the
messenger's sag is a parabola (not a polygon of dropper loads); masts themselves are outside
the cameras' fields and are not drawn. Crossing contact wires meet at one height: in the few
scans where their cross-sections overlap they are drawn one over the other.
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
    "Turnout",
    "WireProfile",
    "WireSamples",
    "WireTypeDims",
    "check_params",
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
MIN_DROPPER_MM = 400.0  # the shortest dropper in systems of 1100 mm and more
SHORTEST_DROPPER_MM = 150.0  # ... and in the lowest systems
OVERLAP_SEPARATION_MM = 200.0
TURNOUT_REACH_MM = 500.0  # the diverging wire runs within this of the track centre
TURNOUT_CROSSING_MM = 250.0  # the wires cross within this of the track centre
CROSSING_PIPE_LENGTH_M = 1.6
CROSSING_PIPE_RADIUS_MM = 12.5
CROSSING_PIPE_PIECES = 16  # the pipe follows the main wire in straight pieces


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
    run's chainages, whichever way the train runs. ``turnout_angle_deg``: None, or the angle
    in plan [2, 10] at which a turnout's diverging contact wire crosses the main one mid-run
    (not with ``overlap``).

    Admitted values (anything else: ``UserError`` naming the parameter and value): ``length_m``
    > 0, ``margin_m`` >= 0, ``roof_height_mm`` 2000-5000, ``curve_radius_m`` None, 0 or >= 150,
    ``curve_direction`` -1, 0 or 1, and ranges ``(low, high)`` with ``low <= high`` within:
    ``contact_height_above_roof_mm`` 800-3000, ``span_m`` 20-80, ``stagger_mm`` and
    ``curve_stagger_mm`` 0-500, ``system_height_mm`` 300-1800, ``dropper_spacing_m`` 2-15,
    ``wear_base_mm`` 0-12.
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
    turnout_angle_deg: float | None = None


_RANGES = {
    "contact_height_above_roof_mm": (800.0, 3000.0),
    "span_m": (20.0, 80.0),
    "stagger_mm": (0.0, 500.0),
    "curve_stagger_mm": (0.0, 500.0),
    "system_height_mm": (300.0, 1800.0),
    "dropper_spacing_m": (2.0, 15.0),
    "wear_base_mm": (0.0, 12.0),
}


def _number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)


def check_params(params: SceneParams) -> None:
    """``UserError`` naming the first parameter outside what :class:`SceneParams` admits."""

    def fail(name: str, expected: str) -> UserError:
        value = getattr(params, name)
        return UserError(f"scene parameter {name} = {value!r}: expected {expected}")

    if not _number(params.length_m) or params.length_m <= 0:
        raise fail("length_m", "a positive length [m]")
    if not _number(params.margin_m) or params.margin_m < 0:
        raise fail("margin_m", "a length >= 0 [m]")
    if not _number(params.roof_height_mm) or not 2000.0 <= params.roof_height_mm <= 5000.0:
        raise fail("roof_height_mm", "2000-5000 mm")
    radius = params.curve_radius_m
    if radius is not None and (not _number(radius) or radius < 0 or 0 < radius < 150):
        raise fail("curve_radius_m", "None, 0 (straight) or at least 150 m")
    if params.curve_direction not in (-1, 0, 1):
        raise fail("curve_direction", "-1, 0 or 1")
    for name, (low, high) in _RANGES.items():
        value = getattr(params, name)
        if not (
            isinstance(value, tuple | list)
            and len(value) == 2
            and all(_number(v) for v in value)
            and low <= value[0] <= value[1] <= high
        ):
            raise fail(name, f"(low, high) with {low:g} <= low <= high <= {high:g}")
    angle = params.turnout_angle_deg
    if angle is not None:
        if not _number(angle) or not 2.0 <= angle <= 10.0:
            raise fail("turnout_angle_deg", "None or an angle of 2-10 degrees")
        if params.overlap:
            raise fail("turnout_angle_deg", "overlap false (a section has an overlap or a turnout)")


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
    wire); between them it sags by ``scallop_per_m2 · L²`` more. Values given at chainages
    ``knots_m`` (interpolated linearly, held beyond the ends) raise the wire further within
    its spans: ``knot_lift_mm`` out of its running position (a turnout's diverging wire rising
    out of contact), ``knot_level_mm`` its running position itself (following another wire's).
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
    knots_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    knot_lift_mm: FloatArray = field(default_factory=lambda: np.zeros(0))
    knot_level_mm: FloatArray = field(default_factory=lambda: np.zeros(0))

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
        if self.knots_m.shape[0]:
            raised = np.interp(c, self.knots_m, self.knot_lift_mm)
            height = height + raised + np.interp(c, self.knots_m, self.knot_level_mm)
            lift = lift + raised
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
class Turnout:
    """Where a turnout's diverging contact wire crosses the main one (line frame)."""

    crossing_m: float  # chainage of the crossing in plan
    stagger_mm: float  # where it is across the track
    height_mm: float  # the main wire's contact point there
    angle_deg: float  # the diverging wire's angle to the main one in plan
    side: int  # +1: the diverging wire leaves to the right (increasing chainage), -1: left
    main: int  # wire ids: the main contact wire, the diverging one
    diverging: int


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
    turnout: Turnout | None = None

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


def _at_knots(knots_m: FloatArray, values: FloatArray, chainage_m: FloatArray) -> FloatArray:
    """Values given at knots (:class:`WireProfile`) at ``[n]`` chainages; zeros without."""
    c = np.asarray(chainage_m, dtype=np.float64)
    if not knots_m.shape[0]:
        return np.zeros_like(c)
    return np.interp(c, knots_m, values)


def _min_dropper_mm(system_mm: FloatArray) -> FloatArray:
    """The shortest dropper a system of ``[n]`` heights [mm] keeps mid-span [mm]."""
    return np.clip(system_mm - 700.0, SHORTEST_DROPPER_MM, MIN_DROPPER_MM)


class _FittingList:
    """Fittings collected wire by wire, sorted by chainage into :class:`Fittings` at the end."""

    def __init__(self) -> None:
        self.kind: list[str] = []
        self.rows: list[tuple[int, float, float, float, float, float, float, float, int]] = []

    def add(
        self,
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
        self.kind.append(kind)
        self.rows.append((wire, c, y, h, hw, hh, angle, reach, curved))

    def build(self) -> Fittings:
        columns = list(zip(*self.rows, strict=True)) if self.rows else [()] * 9
        chainage = np.array(columns[1], dtype=np.float64)
        order = np.argsort(chainage, kind="stable")

        def floats(i: int) -> FloatArray:
            return np.array(columns[i], dtype=np.float64)[order]

        return Fittings(
            kind=np.array(self.kind, dtype=np.str_)[order],
            wire=np.array(columns[0], dtype=np.intp)[order],
            chainage_m=chainage[order],
            y_mm=floats(2),
            h_mm=floats(3),
            half_width_mm=floats(4),
            half_height_mm=floats(5),
            angle_rad=floats(6),
            reach_mm=floats(7),
            curved=np.array(columns[8], dtype=np.intp)[order],
        )


@dataclass(frozen=True)
class _Catenary:
    """One contact wire with its messenger over supports ``[k]`` (spans ``[k-1]``), line frame.

    ``height_mm`` is the contact wire's running height at the supports, ``lift_mm`` its lift
    above it there (both included in its height), ``side`` the side of each support's mast
    (+1 right), ``presag_mm``, ``curvature_per_m`` and ``messenger_sag_mm`` per span,
    ``system_mm`` the system height at each support, ``hanging_m`` the dropper chainages.
    """

    contact_id: int
    letter: str
    support_m: FloatArray
    stagger_mm: FloatArray
    height_mm: FloatArray
    lift_mm: FloatArray
    registered: BoolArray
    side: IndexArray
    in_curve: BoolArray
    presag_mm: FloatArray
    curvature_per_m: FloatArray
    messenger_sag_mm: FloatArray
    system_mm: FloatArray
    hanging_m: FloatArray
    scallop_per_m2: float
    knots_m: FloatArray = field(default_factory=lambda: np.zeros(0))
    knot_lift_mm: FloatArray = field(default_factory=lambda: np.zeros(0))
    knot_level_mm: FloatArray = field(default_factory=lambda: np.zeros(0))


def _lay_catenary(
    cat: _Catenary,
    dims: WireTypeDims,
    params: SceneParams,
    rng: np.random.Generator,
    hot_spots_m: list[float],
    fittings: _FittingList,
) -> tuple[WireProfile, WireProfile]:
    """The contact wire and messenger of ``cat``, its droppers, clamps and steady arms.

    Draws from ``rng``: the wear's undulation, a hot spot at every running registration and at
    each of ``hot_spots_m`` (chainages), the wear's base level.
    """
    contact_id = cat.contact_id
    contact_height = cat.height_mm + cat.lift_mm
    support_lift = cat.lift_mm + _at_knots(cat.knots_m, cat.knot_lift_mm, cat.support_m)
    waves = np.stack(
        [
            rng.uniform(0.1, 0.35, 5),
            rng.uniform(4.0, 80.0, 5),
            rng.uniform(0.0, 2.0 * math.pi, 5),
        ],
        axis=1,
    )
    spots = []
    for j in range(cat.support_m.shape[0]):
        if support_lift[j] == 0.0 and cat.registered[j]:
            amp = rng.uniform(0.3, 2.0) * (1.6 if cat.in_curve[j] else 1.0)
            spots.append((cat.support_m[j], amp, rng.uniform(1.0, 2.5)))
    for c in hot_spots_m:
        spots.append((c, rng.uniform(1.5, 3.0), rng.uniform(3.0, 6.0)))
    contact = WireProfile(
        id=contact_id,
        name=f"CW-{cat.letter}",
        contact=True,
        partner=contact_id + 1,
        support_m=cat.support_m,
        stagger_mm=cat.stagger_mm,
        height_mm=contact_height,
        lift_mm=cat.lift_mm,
        registered=cat.registered,
        sag_mm=cat.presag_mm,
        curvature_per_m=cat.curvature_per_m,
        hanging_m=np.sort(np.concatenate([cat.support_m, cat.hanging_m])),
        scallop_per_m2=cat.scallop_per_m2,
        radius_mm=dims.radius_mm,
        wear_base_mm=rng.uniform(*params.wear_base_mm),
        wear_waves=waves,
        wear_spots=np.array(spots).reshape(-1, 3),
        max_wear_mm=dims.max_wear_mm,
        knots_m=cat.knots_m,
        knot_lift_mm=cat.knot_lift_mm,
        knot_level_mm=cat.knot_level_mm,
    )
    system_low = np.minimum(cat.system_mm[:-1], cat.system_mm[1:])
    sag = np.minimum(cat.messenger_sag_mm, system_low + cat.presag_mm - _min_dropper_mm(system_low))
    messenger = WireProfile(
        id=contact_id + 1,
        name=f"MW-{cat.letter}",
        contact=False,
        partner=contact_id,
        support_m=cat.support_m,
        stagger_mm=cat.stagger_mm,
        height_mm=contact_height + cat.system_mm + dims.height_mm,
        lift_mm=np.zeros(cat.support_m.shape[0]),
        registered=cat.registered,
        sag_mm=np.maximum(sag, 0.0),
        curvature_per_m=cat.curvature_per_m,
        hanging_m=np.zeros(0),
        scallop_per_m2=0.0,
        radius_mm=MESSENGER_DIAMETER_MM / 2.0,
        knots_m=cat.knots_m,
        knot_lift_mm=cat.knot_lift_mm,
        knot_level_mm=cat.knot_level_mm,
    )

    # droppers and their clamps
    hanging = cat.hanging_m
    _, y_cw, h_cw, _, _ = contact.evaluate(hanging)
    _, _, h_mw, _, _ = messenger.evaluate(hanging)
    top_cw = h_cw + dims.height_mm
    for c, y, low, high in zip(hanging, y_cw, top_cw, h_mw, strict=True):
        fittings.add(
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
        fittings.add(
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
    raised = support_lift - cat.lift_mm + _at_knots(cat.knots_m, cat.knot_level_mm, cat.support_m)
    for j in np.flatnonzero(cat.registered).tolist():
        side = int(cat.side[j])
        c = float(cat.support_m[j])
        y = float(cat.stagger_mm[j])
        h = float(contact_height[j]) + float(raised[j])
        slope = math.radians(ARM_SLOPE_DEG)
        top = h + dims.height_mm + 6.0
        half = ARM_LENGTH_MM / 2.0
        fittings.add(
            "steady_arm",
            contact_id,
            c,
            y + side * half * math.cos(slope),
            top + ARM_RADIUS_MM + half * math.sin(slope),
            half,
            ARM_RADIUS_MM,
            side * slope,
            ARM_RADIUS_MM,
            2,
        )
        fittings.add("registration_clamp", contact_id, c, y, top + 6.0, 20.0, 12.0, 0.0, 25.0, 0)
        near, far = -350.0, 2000.0
        fittings.add(
            "registration_tube",
            contact_id,
            c,
            y + side * 0.5 * (near + far),
            h + 320.0,
            0.5 * (far - near),
            TUBE_RADIUS_MM,
            0.0,
            TUBE_RADIUS_MM,
            2,
        )
    return contact, messenger


def _messenger_sag_mm(dims: WireTypeDims, spans_m: FloatArray, tension_n: float) -> FloatArray:
    """A messenger's mid-span sag [mm] over ``[k]`` spans carrying both wires (and fittings)."""
    load = GRAVITY * (dims.area_mm2 * COPPER_DENSITY_KG_PER_MM2_M + MESSENGER_MASS_KG_PER_M + 0.1)
    return 1000.0 * load * spans_m**2 / (8.0 * tension_n)


def _turnout(
    params: SceneParams,
    seed: int,
    main: WireProfile,
    masts_m: FloatArray,
    dims: WireTypeDims,
    fittings: _FittingList,
) -> tuple[Turnout, WireProfile, WireProfile, WireProfile]:
    """A crossed turnout near mid-run (module docstring): the turnout, the main contact wire
    with the crossing's hot spot, the diverging contact wire and its messenger; their fittings
    go to ``fittings``. Drawn from a generator of its own: a seed's scene without a turnout
    stays what it was."""
    assert params.turnout_angle_deg is not None
    rng = np.random.default_rng([seed, 0x7A40])
    angle = math.radians(params.turnout_angle_deg)
    # the crossing: mid-run, near the track centre, 5 m or more from the main line's masts
    middle = params.start_chainage_m + 0.5 * params.length_m
    half = min(max(0.1 * params.length_m, 15.0), 0.4 * params.length_m)
    candidates = np.linspace(middle - half, middle + half, 201)
    _, y_main, _, _, _ = main.evaluate(candidates)
    clear = np.min(np.abs(candidates[:, None] - masts_m[None, :]), axis=1) >= 5.0
    good = clear & (np.abs(y_main) <= TURNOUT_CROSSING_MM)
    if np.any(good):
        crossing = float(rng.choice(candidates[good]))
    else:
        crossing = float(candidates[np.argmin(np.where(clear, np.abs(y_main), np.inf))])
    _, y_at, h_at, g_at, _ = main.evaluate(np.array([crossing]))
    y0, h0, g0 = float(y_at[0]), float(h_at[0]), float(g_at[0])

    # the diverging wire: straight in plan at the angle to the main one, from its anchor on
    # the far side (crossing the track at 10 mm/m or more, whatever the main wire's stagger)
    side = int(rng.choice([-1, 1]))
    heading = math.atan(g0 / 1000.0)
    if side * math.tan(heading + side * angle) < 0.01:
        side = -side
    slope = 1000.0 * math.tan(heading + side * angle)  # dy/dc [mm/m]
    spans = rng.uniform(*params.span_m, 3)
    support = crossing + np.array([-spans[0], spans[1], spans[1] + spans[2]])
    stagger = y0 + slope * (support - crossing)
    hanging = _hanging_points(support, params.dropper_spacing_m, rng)
    presag = rng.uniform(0.0, 1.0, 2) * np.diff(support)
    system = np.full(3, rng.uniform(*params.system_height_mm))
    messenger_sag = _messenger_sag_mm(dims, np.diff(support), rng.uniform(14000.0, 21000.0))
    # its lift over the main wire's running height, by where it is across the track: down from
    # the anchor to running height within the pantograph's reach, running through the
    # crossing, rising slowly beyond it toward its next support
    enter = -side * max(rng.uniform(300.0, TURNOUT_REACH_MM), 100.0 - side * y0)
    rise = rng.uniform(400.0, 700.0)  # [mm] across the track beyond the crossing

    def at(y_mm: float) -> float:
        return crossing + (y_mm - y0) / slope

    lift = np.array(
        [
            (at(enter - side * 200.0), rng.uniform(80.0, 150.0)),
            (at(enter), 0.0),
            (crossing, 0.0),
            (at(y0 + side * rise), rng.uniform(50.0, 100.0)),
        ]
    )
    lift = lift[(lift[:, 0] > support[0]) & (lift[:, 0] < support[1])]
    raised = rng.uniform(250.0, 400.0)
    ends = np.array(
        [(support[0], rng.uniform(500.0, 800.0)), (support[1], raised), (support[2], raised)]
    )
    lift = np.concatenate([ends[:1], lift, ends[1:]])
    # its running position follows the main wire's height where the pantograph may touch both
    # (the droppers are cut for it): its own sags, levelled every 0.25 m
    hanging_m = np.sort(np.concatenate([support, hanging]))
    shape = WireProfile(
        id=-1,
        name="",
        contact=True,
        partner=-1,
        support_m=support,
        stagger_mm=stagger,
        height_mm=np.zeros(3),
        lift_mm=np.zeros(3),
        registered=np.ones(3, dtype=bool),
        sag_mm=presag,
        curvature_per_m=np.zeros(2),
        hanging_m=hanging_m,
        scallop_per_m2=main.scallop_per_m2,
        radius_mm=dims.radius_mm,
    )
    first = max(at(enter - side * 200.0) - 2.0, support[0])
    last = min(at(y0 + side * rise) + 2.0, support[1])
    level_m = np.linspace(first, last, max(2, math.ceil((last - first) / 0.25) + 1))
    level = main.evaluate(level_m)[2] - shape.evaluate(level_m)[2]
    knots_m = np.union1d(lift[:, 0], level_m)
    catenary = _Catenary(
        contact_id=main.id + 2,
        letter="T",
        support_m=support,
        stagger_mm=stagger,
        height_mm=np.zeros(3),
        lift_mm=np.zeros(3),
        registered=np.array([False, True, True]),  # anchored at its first support
        side=np.full(3, side, dtype=np.intp),
        in_curve=np.zeros(3, dtype=bool),
        presag_mm=presag,
        curvature_per_m=np.zeros(2),
        messenger_sag_mm=messenger_sag,
        system_mm=system,
        hanging_m=hanging,
        scallop_per_m2=main.scallop_per_m2,
        knots_m=knots_m,
        knot_lift_mm=np.interp(knots_m, lift[:, 0], lift[:, 1]),
        knot_level_mm=np.interp(knots_m, level_m, level),
    )
    contact, messenger = _lay_catenary(catenary, dims, params, rng, [crossing], fittings)
    spot = np.array([[crossing, rng.uniform(1.5, 3.0), rng.uniform(3.0, 6.0)]])
    main = replace(main, wear_spots=np.concatenate([main.wear_spots, spot]))

    # the cross-over pipe above both wires, clamped to the main wire at its ends
    edges = crossing + CROSSING_PIPE_LENGTH_M * np.linspace(-0.5, 0.5, CROSSING_PIPE_PIECES + 1)
    pieces = 0.5 * (edges[:-1] + edges[1:])
    _, y_pipe, h_pipe, _, _ = main.evaluate(pieces)
    pipe_h = h_pipe + dims.height_mm + 3.0 + CROSSING_PIPE_RADIUS_MM
    reach = 500.0 * CROSSING_PIPE_LENGTH_M / CROSSING_PIPE_PIECES
    r = CROSSING_PIPE_RADIUS_MM
    for c, y, h in zip(pieces, y_pipe, pipe_h, strict=True):
        fittings.add("crossing_pipe", main.id, float(c), float(y), float(h), r, r, 0.0, reach, 0)
    for k in (0, -1):
        low = float(h_pipe[k]) + 0.45 * dims.height_mm
        high = float(pipe_h[k])
        c, y = float(pieces[k]), float(y_pipe[k])
        mid, half_h = 0.5 * (low + high), 0.5 * (high - low)
        fittings.add("crossing_clamp", main.id, c, y, mid, 10.0, half_h, 0.0, 15.0, 0)
    turnout = Turnout(
        crossing_m=crossing,
        stagger_mm=y0,
        height_mm=h0,
        angle_deg=float(params.turnout_angle_deg),
        side=side,
        main=main.id,
        diverging=contact.id,
    )
    return turnout, main, contact, messenger


def generate_scene(params: SceneParams, seed: int) -> Scene:
    """Lay out a section of line covering the run plus ``margin_m`` on each side.

    ``UserError`` naming the parameter for values :class:`SceneParams` does not admit.
    """
    check_params(params)
    rng = np.random.default_rng([seed, 0x5CE7E])
    dims = wire_type_dims(params.wire_type)
    run_start = params.start_chainage_m
    start = run_start - params.margin_m
    end = run_start + params.length_m + params.margin_m
    lo_h, hi_h = params.contact_height_above_roof_mm

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
    # margins from the range's ends, narrower in ranges under 400 mm (and 200 mm)
    start_margin = min(1.0, (hi_h - lo_h) / 400.0)
    step_margin = min(1.0, (hi_h - lo_h) / 200.0)
    above = np.empty(n_masts)
    above[0] = rng.uniform(
        lo_h + 150.0 * start_margin, min(hi_h - 250.0 * start_margin, lo_h + 900.0)
    )
    for i in range(1, n_masts):
        step = rng.normal(0.0, 40.0)
        if rng.random() < 0.15:
            step += rng.choice([-1, 1]) * rng.uniform(1.0, 2.5) * spans[i - 1]  # up to 2.5 ‰
        above[i] = np.clip(
            above[i - 1] + step, lo_h + 80.0 * step_margin, hi_h - 120.0 * step_margin
        )
    height = roof + above
    presag = rng.uniform(0.0, 1.0, n_masts - 1) * spans  # 0-1/1000 of the span, mm
    system = np.full(n_masts, rng.uniform(*params.system_height_mm))
    system += rng.normal(0.0, 20.0, n_masts)
    system = np.clip(system, *params.system_height_mm)
    contact_mass = dims.area_mm2 * COPPER_DENSITY_KG_PER_MM2_M
    contact_tension = rng.uniform(15000.0, 30000.0)
    messenger_sag = _messenger_sag_mm(dims, spans, rng.uniform(14000.0, 21000.0))
    scallop = 1000.0 * GRAVITY * contact_mass / (8.0 * contact_tension)  # mm per m²

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

    fittings = _FittingList()
    wires: list[WireProfile] = []
    for number, ((first, last), wire_lift, wire_stagger, anchor) in enumerate(
        zip(wire_ranges, lift, staggers, anchors, strict=True)
    ):
        idx = np.arange(first, last + 1)
        hanging = _hanging_points(support[idx], params.dropper_spacing_m, rng)
        catenary = _Catenary(
            contact_id=2 * number,
            letter="AB"[number] if len(wire_ranges) > 1 else "A",
            support_m=support[idx],
            stagger_mm=wire_stagger[idx],
            height_mm=height[idx],
            lift_mm=wire_lift[idx],
            registered=np.array([i not in anchor for i in idx]),
            side=mast_side[idx],
            in_curve=mast_in_curve[idx],
            presag_mm=presag[idx[:-1]],
            curvature_per_m=kappa[idx[:-1]],
            messenger_sag_mm=messenger_sag[idx[:-1]],
            system_mm=system[idx],
            hanging_m=hanging,
            scallop_per_m2=scallop,
        )
        transfer = [float(support[overlap_masts[1]])] if overlap_masts else []
        wires += _lay_catenary(catenary, dims, params, rng, transfer, fittings)
    turnout = None
    if params.turnout_angle_deg is not None:
        turnout, wires[0], diverging, messenger = _turnout(
            params, seed, wires[0], support, dims, fittings
        )
        wires += [diverging, messenger]

    return Scene(
        params=params,
        seed=seed,
        wire_type=dims,
        start_m=float(support[0]),
        end_m=float(support[-1]),
        masts=masts,
        wires=tuple(wires),
        fittings=fittings.build(),
        curve_start_m=curve_start,
        curve_end_m=curve_end,
        curvature_per_m=float(curvature) if math.isfinite(curve_start) else 0.0,
        overlap_masts=overlap_masts,
        turnout=turnout,
    )
