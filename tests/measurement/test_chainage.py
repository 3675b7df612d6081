"""Registration points from the stagger and the alignment of encoder positions to masts."""

from __future__ import annotations

import itertools
import math
import tracemalloc
from dataclasses import dataclass

import numpy as np
import pytest

from catenary.measurement.chainage import (
    IDLE_RELEASE_M,
    ChainageAlignment,
    TurningPointFinder,
    align_to_register,
    span_index,
)

SPACING_M = 0.015  # 54 km/h at 1000 scans/s
PULSE_M = 0.00125  # the encoder's pulse
START_M = 12000.0
VIEW_MM = 600.0  # the cameras see the wire within ±600 mm
END_M = 10.0
"""Registrations this close to a run's ends (where one side's fits lack samples) are not
expected, nor checked."""

TURNING_STRAIGHT_M = 0.1
"""Turning points on straight track with 1 mm of stagger noise: two 8 m quadratics of 530
samples cross within about a centimetre (RMS); ten times that."""

TURNING_CURVE_M = 0.2
"""In curves (chords of an arc either side, the curvature changing at the curve's start)."""

ALIGNED_M = 0.2
"""Aligned chainage against the truth over the whole run (the brief's figure: a 20 km run
with 0.5 % scale error and 8 m start error)."""


@dataclass
class Run:
    """A synthetic run: per sample the wire, encoder position, true chainage and stagger; the
    register; the true encoder positions of the registrations."""

    wire: np.ndarray
    position_m: np.ndarray
    chainage_m: np.ndarray
    stagger_mm: np.ndarray
    masts_m: np.ndarray
    turning_m: np.ndarray
    spurious_m: np.ndarray
    header_start_m: float
    direction: str


def _polyline(chainage, support, value, curvature):
    """Stagger [mm] at chainages: linear between supports plus the versine of each span's
    curvature [1/m] (the wire a chord of the curved track)."""
    k = np.clip(np.searchsorted(support, chainage, side="right") - 1, 0, support.shape[0] - 2)
    length = support[k + 1] - support[k]
    s = chainage - support[k]
    t = s / length
    return value[k] + (value[k + 1] - value[k]) * t + 1000.0 * curvature[k] * s * (length - s) / 2


def make_run(
    length_m: float = 2000.0,
    seed: int = 0,
    *,
    direction: str = "increasing",
    scale_error: float = 0.005,
    start_error_m: float = 8.0,
    noise_mm: float = 1.0,
    curve_radius_m: float = 0.0,
    overlap: bool = False,
    missed: tuple[int, ...] = (),
    anchors: tuple[int, ...] = (),
    spurious: tuple[int, ...] = (),
) -> Run:
    """A line of masts 40-65 m apart (30-45 m in the curve) with a zigzag of ±200-400 mm on
    straight track; with ``curve_radius_m`` the second half of the run is a curve bending
    right, every registration outside (150-300 mm) and the wire swinging inward mid-span.

    Masts and spans are numbered from the run's start. ``missed``: masts whose registration
    the processor does not see (no rows within 6 m of it); ``anchors``: spans with a mast
    mid-way in the register that registers no wire; ``spurious``: spans with a 30 m piece of
    another wire kinked mid-span (20 mm/m either side), at no mast. ``overlap``: a second wire
    over three masts mid-run, the first one raised and pulled out toward its anchor, each in
    view only within ±600 mm.
    """
    rng = np.random.default_rng(seed)
    sign = 1.0 if direction == "increasing" else -1.0
    low = START_M - 100.0 if sign > 0 else START_M - length_m - 100.0
    high = low + length_m + 200.0
    curve_from = low + 100.0 + 0.5 * length_m if curve_radius_m else math.inf
    masts = [low]
    while masts[-1] < high:
        in_curve = masts[-1] >= curve_from
        masts.append(masts[-1] + (rng.uniform(30.0, 45.0) if in_curve else rng.uniform(40.0, 65.0)))
    support = np.array(masts)
    kappa = np.where(support[:-1] >= curve_from, 1.0 / max(curve_radius_m, 1.0), 0.0)
    alternate = np.where(np.arange(support.shape[0]) % 2 == 0, 1.0, -1.0)
    stagger = alternate * rng.uniform(200.0, 400.0, support.shape[0])
    in_curve = support >= curve_from
    stagger[in_curve] = -rng.uniform(150.0, 300.0, np.count_nonzero(in_curve))  # outside: left
    distance = np.arange(0.0, length_m, SPACING_M)
    chainage = START_M + sign * distance
    ahead = np.argsort(sign * (support - START_M))
    ahead = ahead[sign * (support[ahead] - START_M) > 0.0]

    wires = [(0, support, stagger, kappa)]
    if overlap:
        assert not curve_radius_m
        j1 = int(ahead[np.argmin(np.abs(sign * (support[ahead] - START_M) - 0.5 * length_m))])
        j0, j2 = j1 - 1, j1 + 1
        side = alternate[j0]  # the zigzag goes on; the wires' anchors on the side of j0
        stagger[j0], stagger[j1], stagger[j2] = 300.0 * side, -100.0 * side, 300.0 * side
        a_y = stagger[: j2 + 2].copy()
        a_y[j1], a_y[j2], a_y[j2 + 1] = 0.0, 500.0 * side, 2800.0 * side
        b_y = stagger[j0 - 1 :].copy()
        b_y[0], b_y[1], b_y[2] = 2800.0 * side, 500.0 * side, -200.0 * side
        wires = [(0, support[: j2 + 2], a_y, kappa), (1, support[j0 - 1 :], b_y, kappa)]
    rows = []
    for number, wc, wy, wk in wires:
        y = _polyline(chainage, wc, wy, wk)
        inside = (chainage >= wc[0]) & (chainage <= wc[-1]) & (np.abs(y) <= VIEW_MM)
        for j in missed:
            inside &= np.abs(chainage - support[ahead[j]]) > 6.0
        rows.append((np.full(np.count_nonzero(inside), number), inside, sign * y[inside]))
    extra = []
    for number, i in enumerate(spurious, start=7):
        middle = 0.5 * (support[ahead[i]] + support[ahead[i + 1]])
        inside = np.abs(chainage - middle) <= 15.0
        y = 200.0 - 20.0 * np.abs(chainage[inside] - middle)
        rows.append((np.full(y.shape, number), inside, y))
        extra.append(abs(middle - START_M) * (1.0 + scale_error))
    register = np.sort(
        np.concatenate(
            [support, [0.5 * (support[ahead[i]] + support[ahead[i + 1]]) for i in anchors]]
        )
    )
    registered = np.delete(sign * (support[ahead] - START_M), list(missed))
    d = np.concatenate([distance[r[1]] for r in rows])
    order = np.argsort(d, kind="stable")
    stagger_mm = np.concatenate([r[2] for r in rows]) + rng.normal(0.0, noise_mm, d.shape[0])
    return Run(
        wire=np.concatenate([r[0] for r in rows]).astype(np.int64)[order],
        position_m=(np.floor(d * (1.0 + scale_error) / PULSE_M + 1e-9) * PULSE_M)[order],
        chainage_m=np.concatenate([chainage[r[1]] for r in rows])[order],
        stagger_mm=stagger_mm[order],
        masts_m=register,
        turning_m=registered[(registered > END_M) & (registered < length_m - END_M)]
        * (1.0 + scale_error),
        spurious_m=np.sort(np.array(extra)),
        header_start_m=START_M + start_error_m,
        direction=direction,
    )


def inner(run: Run, points: np.ndarray) -> np.ndarray:
    """The points more than ``END_M`` from the run's ends."""
    end = float(run.position_m.max())
    scale = end / float(np.max(np.abs(run.chainage_m - START_M)))
    return points[(points > END_M * scale) & (points < end - END_M * scale)]


def find(run: Run) -> np.ndarray:
    finder = TurningPointFinder()
    finder.push(run.wire, run.position_m, run.stagger_mm)
    return inner(run, finder.finish())


def assert_turning_points(found: np.ndarray, truth: np.ndarray, tolerance_m: float) -> None:
    assert found.shape == truth.shape, (found, truth)
    np.testing.assert_allclose(found, truth, rtol=0.0, atol=tolerance_m)


# -- registration points ------------------------------------------------------------------


def test_straight_zigzag_with_noise() -> None:
    run = make_run(2000.0, seed=1)
    assert_turning_points(find(run), run.turning_m, TURNING_STRAIGHT_M)


def test_noise_free_zigzag() -> None:
    run = make_run(600.0, seed=2, noise_mm=0.0)
    assert_turning_points(find(run), run.turning_m, 0.01)


def test_noisy_zigzag_3mm() -> None:
    # three times the processor's worst sample noise still gives the same points
    run = make_run(1000.0, seed=3, noise_mm=3.0)
    assert_turning_points(find(run), run.turning_m, 2.0 * TURNING_STRAIGHT_M)


@pytest.mark.parametrize("radius_m", [300.0, 1200.0])
def test_curve_arcs(radius_m: float) -> None:
    run = make_run(2000.0, seed=4, curve_radius_m=radius_m)
    assert_turning_points(find(run), run.turning_m, TURNING_CURVE_M)


def test_overlap_second_wire_raised_away() -> None:
    run = make_run(1000.0, seed=5, overlap=True)
    assert set(np.unique(run.wire)) == {0, 1}
    assert_turning_points(find(run), run.turning_m, TURNING_STRAIGHT_M)


def test_missed_registration_anchor_and_spurious_kink() -> None:
    run = make_run(1500.0, seed=6, missed=(7,), anchors=(3,), spurious=(12,))
    found = find(run)
    expected = np.sort(np.concatenate([run.turning_m, run.spurious_m]))
    assert_turning_points(found, expected, TURNING_STRAIGHT_M)


def test_decreasing_direction_mirrors_the_stagger() -> None:
    run = make_run(1500.0, seed=7, direction="decreasing", curve_radius_m=800.0)
    assert_turning_points(find(run), run.turning_m, TURNING_CURVE_M)


def test_straight_line_has_no_turning_point() -> None:
    position = np.arange(0.0, 300.0, SPACING_M)
    rng = np.random.default_rng(8)
    for stagger in (-200.0 + 12.0 * position, 50.0 + 0.0 * position):
        finder = TurningPointFinder()
        noisy = stagger + rng.normal(0.0, 1.0, position.shape)
        finder.push(np.zeros(position.shape, dtype=int), position, noisy)
        assert finder.finish().shape == (0,)


def test_streaming_in_uneven_pushes_equals_one_push() -> None:
    run = make_run(1200.0, seed=9, overlap=True)
    # wire 1 released 20 m behind wire 0, in pushes of 1 to 5000 rows, a few NaN rows
    rng = np.random.default_rng(10)
    stagger = run.stagger_mm.copy()
    stagger[rng.choice(stagger.shape[0], 50, replace=False)] = np.nan
    one = TurningPointFinder()
    one.push(run.wire, run.position_m, stagger)
    whole = one.finish()
    release = run.position_m + np.where(run.wire == 1, 20.0, 0.0)
    order = np.argsort(release, kind="stable")
    finder = TurningPointFinder()
    start = 0
    while start < order.shape[0]:
        stop = start + int(rng.integers(1, 5000))
        rows = order[start:stop]
        finder.push(run.wire[rows], run.position_m[rows], stagger[rows])
        start = stop
    streamed = inner(run, finder.finish())
    whole = inner(run, whole)
    assert streamed.shape == whole.shape
    np.testing.assert_allclose(streamed, whole, rtol=0.0, atol=1e-6)
    assert_turning_points(streamed, run.turning_m, TURNING_STRAIGHT_M)


def test_a_gap_in_a_wire_and_a_wire_resumed() -> None:
    run = make_run(1500.0, seed=11)
    gap = (run.position_m > 500.0) & (run.position_m < 620.0)
    finder = TurningPointFinder()
    half = run.position_m < 900.0
    for part in (~gap & half, ~gap & ~half):
        finder.push(run.wire[part], run.position_m[part], run.stagger_mm[part])
    found = inner(run, finder.finish())
    # registrations in the gap are not found, those a window clear of its ends are
    truth = run.turning_m
    clear = (truth < 500.0 - 12.0) | (truth > 620.0 + 12.0)
    inside = (truth > 500.0) & (truth < 620.0)
    assert np.count_nonzero(inside) >= 1
    distance = np.min(np.abs(found[:, None] - truth[None, :]), axis=1)
    assert np.all(distance < TURNING_STRAIGHT_M)
    hit = np.min(np.abs(found[:, None] - truth[None, :]), axis=0) < TURNING_STRAIGHT_M
    assert np.all(hit[clear]) and not np.any(hit[inside])


def test_a_wire_released_while_idle_continues_in_its_last_bin() -> None:
    # wire 1 stops; wire 0 runs on past IDLE_RELEASE_M, which releases wire 1; then wire 1's
    # last held rows arrive, in the bin of its last sample (a chain releasing an ended wire)
    finder = TurningPointFinder()
    finder.push([1, 1], [10.0, 10.05], [100.0, 100.5])
    far = np.arange(10.0, 10.0 + IDLE_RELEASE_M + 50.0, 0.5)
    finder.push(np.zeros(far.shape, np.int64), far, np.zeros(far.shape))
    finder.push([1], [10.06], [100.6])
    assert finder.finish().shape == (0,)


def test_memory_does_not_grow_with_the_run() -> None:
    run = make_run(6000.0, seed=12, noise_mm=0.5)
    finder = TurningPointFinder()
    edges = np.searchsorted(run.position_m, np.arange(0.0, 6100.0, 50.0))
    tracemalloc.start()
    try:
        used = []
        for a, b in itertools.pairwise(edges):
            finder.push(run.wire[a:b], run.position_m[a:b], run.stagger_mm[a:b])
            used.append(tracemalloc.get_traced_memory()[0])
    finally:
        tracemalloc.stop()
    # after the first km, only the output (one float per span) may grow: 100 spans here
    assert used[-1] - used[20] < 40_000
    assert inner(run, finder.finish()).shape == run.turning_m.shape


def test_push_rejects_positions_going_back() -> None:
    finder = TurningPointFinder()
    finder.push(np.array([0, 0]), np.array([1.0, 2.0]), np.array([0.0, 1.0]))
    finder.push(np.array([1]), np.array([0.5]), np.array([0.0]))  # another wire may lag
    with pytest.raises(ValueError, match="wire 0"):
        finder.push(np.array([0]), np.array([1.5]), np.array([0.0]))
    with pytest.raises(ValueError, match="shape"):
        finder.push(np.array([0]), np.array([1.5, 2.0]), np.array([0.0]))
    assert finder.finish().shape == (0,)
    with pytest.raises(RuntimeError, match="after finish"):
        finder.push(np.array([0]), np.array([3.0]), np.array([0.0]))


# -- alignment ------------------------------------------------------------------------------


def chainage_error(alignment: ChainageAlignment, run: Run) -> float:
    return float(np.max(np.abs(alignment.chainage_m(run.position_m) - run.chainage_m)))


def test_20_km_run_aligned_within_0_2_m() -> None:
    run = make_run(20000.0, seed=13, scale_error=0.005, start_error_m=8.0, noise_mm=1.0)
    found = find(run)
    alignment = align_to_register(found, run.masts_m, run.header_start_m, run.direction)
    assert alignment.aligned, alignment.reason
    assert alignment.turning_points == found.shape[0] == run.turning_m.shape[0]
    assert alignment.matched == found.shape[0]
    assert chainage_error(alignment, run) < ALIGNED_M
    assert alignment.scale * 1.005 == pytest.approx(1.0, abs=1e-5)
    assert alignment.residual_rms_m < 0.05
    # without alignment the end of the run is tens of metres off
    header = ChainageAlignment.unaligned(run.header_start_m, run.direction, "none")
    assert chainage_error(header, run) > 100.0


@pytest.mark.parametrize(
    ("direction", "scale_error", "start_error_m", "curve_radius_m"),
    [
        ("decreasing", -0.006, -10.0, 0.0),
        ("increasing", 0.006, 10.0, 900.0),
        ("decreasing", 0.002, 3.0, 700.0),
    ],
)
def test_runs_with_missed_anchors_and_spurious_points(
    direction: str, scale_error: float, start_error_m: float, curve_radius_m: float
) -> None:
    run = make_run(
        5000.0,
        seed=14,
        direction=direction,
        scale_error=scale_error,
        start_error_m=start_error_m,
        curve_radius_m=curve_radius_m,
        missed=(0, 5, 6, 40),
        anchors=(2, 30),
        spurious=(0, 22, 61),
    )
    found = find(run)
    assert found.shape[0] == run.turning_m.shape[0] + 3
    alignment = align_to_register(found, run.masts_m, run.header_start_m, direction)
    assert alignment.aligned, alignment.reason
    assert alignment.matched == run.turning_m.shape[0]
    assert chainage_error(alignment, run) < ALIGNED_M


def synthetic_points(seed: int, scale_error: float, start_error_m: float, sign: int):
    """Register, true chainage at each encoder position, and turning points with 5 cm of
    noise, 10 % of the registrations missed, and spurious points at 5 % of the masts."""
    rng = np.random.default_rng(seed)
    masts = START_M - 200.0 + np.cumsum(rng.uniform(40.0, 65.0, 600))
    if sign < 0:
        masts = masts - masts[-1] + START_M + 200.0
    distance = sign * (masts - START_M)
    real = distance[(distance > 0.0) & (distance < 25000.0)]
    real = real[rng.random(real.shape[0]) > 0.1]
    fake = rng.uniform(0.0, 25000.0, real.shape[0] // 20)
    points = np.concatenate([real + rng.normal(0.0, 0.05, real.shape[0]), fake])
    return masts, np.sort(points) * (1.0 + scale_error), START_M + start_error_m


@pytest.mark.parametrize("sign", [1, -1])
@pytest.mark.parametrize(("scale_error", "start_error_m"), [(0.006, -10.0), (-0.006, 10.0)])
def test_alignment_of_noisy_points(sign: int, scale_error: float, start_error_m: float) -> None:
    direction = "increasing" if sign > 0 else "decreasing"
    masts, points, header = synthetic_points(15, scale_error, start_error_m, sign)
    alignment = align_to_register(points, masts, header, direction)
    assert alignment.aligned, alignment.reason
    position = np.linspace(0.0, 25000.0 * (1.0 + scale_error), 1001)
    truth = START_M + sign * position / (1.0 + scale_error)
    assert np.max(np.abs(alignment.chainage_m(position) - truth)) < ALIGNED_M
    assert alignment.matched < alignment.turning_points  # the fakes near no mast are left
    assert alignment.residual_rms_m < 0.1


def test_too_few_turning_points_give_the_header() -> None:
    masts = START_M + np.arange(-2, 20) * 50.0
    alignment = align_to_register([49.0, 101.0], masts, START_M + 1.0, "decreasing")
    assert not alignment.aligned
    assert "2 turning points" in alignment.reason
    assert alignment.turning_points == 2
    assert alignment.chainage_m(np.array([0.0, 100.0])) == pytest.approx(
        [START_M + 1.0, START_M - 99.0]
    )


def test_points_that_match_no_register_give_the_header() -> None:
    rng = np.random.default_rng(16)
    masts = START_M + np.cumsum(rng.uniform(40.0, 65.0, 100))
    points = np.sort(rng.uniform(0.0, 4000.0, 80))
    alignment = align_to_register(points, masts, START_M, "increasing")
    assert not alignment.aligned
    assert "80" in alignment.reason  # names the counts
    assert alignment.offset_m == START_M and alignment.scale == 1.0


def test_direction_must_be_known() -> None:
    with pytest.raises(ValueError, match="direction"):
        align_to_register([1.0, 2.0, 3.0], [0.0, 1.0, 2.0], 0.0, "up")
    with pytest.raises(ValueError, match="direction"):
        ChainageAlignment.unaligned(0.0, "north", "")


def test_unaligned_is_the_header_model() -> None:
    alignment = ChainageAlignment.unaligned(500.0, "decreasing", "no register")
    assert not alignment.aligned and alignment.reason == "no register"
    assert alignment.direction_sign == -1
    np.testing.assert_allclose(alignment.chainage_m([[0.0, 10.0]]), [[500.0, 490.0]])


# -- spans ----------------------------------------------------------------------------------


def test_span_index() -> None:
    boundaries = np.array([100.0, 150.0, 150.0, 210.0])
    chainage = np.array([99.9, 100.0, 149.99, 150.0, 209.9, 210.0, np.nan])
    np.testing.assert_array_equal(span_index(chainage, boundaries), [-1, 0, 0, 2, 2, -1, -1])
    assert span_index(np.array([[120.0]]), boundaries).shape == (1, 1)
    np.testing.assert_array_equal(span_index([5.0], [1.0]), [-1])
    with pytest.raises(ValueError, match="ascending"):
        span_index([1.0], [2.0, 1.0])
