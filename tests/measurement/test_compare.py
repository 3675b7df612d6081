"""Repeatability of two runs over the same section (the paper's figure 16)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import pytest

from catenary.errors import UserError
from catenary.measurement.compare import Comparison, RunProfile, compare_profiles

START_M = 12000.0
LENGTH_M = 300.0
NOMINAL_MM = 12.9  # CTA120


@dataclass(frozen=True)
class Line:
    """A synthetic section: a main wire's zigzag and an overlap wire, and their wear."""

    masts_m: np.ndarray
    stagger_at_masts_mm: np.ndarray
    spots: np.ndarray  # (k, 3): chainage [m], depth [mm], width σ [m]
    overlap_m: tuple[float, float]

    def stagger_mm(self, wire: str, c: np.ndarray) -> np.ndarray:
        main = np.interp(c, self.masts_m, self.stagger_at_masts_mm)
        if wire == "main":
            return main
        # the overlap wire: 200 mm beside the main one at its middle, moving away to the ends
        low, high = self.overlap_m
        middle = 0.5 * (low + high)
        return main + 200.0 + 150.0 * np.abs(c - middle) / (0.5 * (high - low))

    def thickness_mm(self, wire: str, c: np.ndarray) -> np.ndarray:
        base = 0.6 + 0.15 * np.sin(2.0 * math.pi * (c - START_M) / 37.0)
        if wire == "overlap":
            return NOMINAL_MM - 0.3 - 0.1 * np.cos(2.0 * math.pi * (c - START_M) / 23.0)
        where, depth, sigma = self.spots.T
        spots = depth * np.exp(-0.5 * ((c[:, None] - where) / sigma) ** 2)
        return NOMINAL_MM - base - spots.sum(axis=1)


def make_line(seed: int = 7) -> Line:
    rng = np.random.default_rng(seed)
    spans = rng.uniform(45.0, 60.0, 12)
    masts = START_M - 40.0 + np.concatenate([[0.0], np.cumsum(spans)])
    sign = np.where(np.arange(masts.shape[0]) % 2 == 0, 1.0, -1.0)
    stagger = sign * rng.uniform(200.0, 350.0, masts.shape[0])
    # hot spots at the masts and mid-span: 0.5-1.5 mm deep over a few metres
    middles = 0.5 * (masts[:-1] + masts[1:])
    where = np.concatenate([masts, middles])
    spots = np.column_stack(
        [where, rng.uniform(0.5, 1.5, where.shape[0]), rng.uniform(1.0, 2.0, where.shape[0])]
    )
    return Line(masts, stagger, spots, (START_M + 110.0, START_M + 200.0))


def sample_run(
    line: Line,
    rng: np.random.Generator,
    *,
    spacing_m: float,
    chainage_offset_m: float,
    thickness_noise_mm: float,
    numbers: dict[str, int],
    start_m: float = START_M,
    end_m: float = START_M + LENGTH_M,
    decreasing: bool = False,
    stagger_noise_mm: float = 1.0,
) -> RunProfile:
    """A run's samples: true positions every ``spacing_m`` (±20 %), recorded at chainage
    ``true + chainage_offset_m``, with noise; wire numbers per run from ``numbers``."""
    steps = spacing_m * rng.uniform(0.8, 1.2, math.ceil((end_m - start_m) / spacing_m) + 10)
    true_m = start_m + rng.uniform(0.0, spacing_m) + np.cumsum(steps)
    true_m = true_m[true_m < end_m]
    columns: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    for name, number in numbers.items():
        c = true_m
        if name == "overlap":
            c = c[(c >= line.overlap_m[0]) & (c <= line.overlap_m[1])]
        n = c.shape[0]
        columns.append(
            (
                c + chainage_offset_m,
                np.full(n, number),
                line.stagger_mm(name, c) + rng.normal(0.0, stagger_noise_mm, n),
                line.thickness_mm(name, c) + rng.normal(0.0, thickness_noise_mm, n),
            )
        )
    chainage, wire, stagger, thickness = (
        np.concatenate(parts) for parts in zip(*columns, strict=True)
    )
    order = np.argsort(chainage, kind="stable")
    if decreasing:
        order = order[::-1]
    return RunProfile(chainage[order], wire[order], stagger[order], thickness[order])


def expected_share(sigma_a_mm: float, sigma_b_mm: float, tolerance_mm: float = 0.1) -> float:
    """Share within the tolerance of ``B - A`` for independent noise, B interpolated."""
    sigma = math.sqrt(sigma_a_mm**2 + 2.0 / 3.0 * sigma_b_mm**2)
    return math.erf(tolerance_mm / (sigma * math.sqrt(2.0)))


@pytest.fixture(scope="module")
def line() -> Line:
    return make_line()


def two_runs(
    line: Line, sigma_a_mm: float = 0.02, sigma_b_mm: float = 0.03, offset_m: float = 0.317, **b
) -> tuple[RunProfile, RunProfile]:
    rng = np.random.default_rng(11)
    run_a = sample_run(
        line,
        rng,
        spacing_m=0.0139,
        chainage_offset_m=0.0,
        thickness_noise_mm=sigma_a_mm,
        numbers={"main": 0, "overlap": 1},
    )
    options = {"numbers": {"main": 1, "overlap": 0}, **b}
    run_b = sample_run(
        line,
        rng,
        spacing_m=0.0163,
        chainage_offset_m=offset_m,
        thickness_noise_mm=sigma_b_mm,
        **options,
    )
    return run_a, run_b


def test_overlap_wires_are_paired_across_numberings_and_the_shift_recovered(line: Line) -> None:
    run_a, run_b = two_runs(line)
    result = compare_profiles(run_a, run_b)
    assert set(result.wire_pairs) == {(0, 1), (1, 0)}
    assert result.shift_m == pytest.approx(0.317, abs=0.005)  # off the coarse grid
    # the stagger of the two runs lies on each other to their noise (1 mm each)
    assert result.stagger_rms_mm == pytest.approx(math.sqrt(1.0 + 2.0 / 3.0), rel=0.1)
    # every sample of A where B runs along it, both wires
    # (B's chainage is 0.317 m ahead, so that after the shift the runs cover the same line)
    along_main = np.count_nonzero(run_a.wire == 0)
    assert np.count_nonzero(result.wire == 0) == pytest.approx(along_main, abs=3)
    along_overlap = np.count_nonzero(run_a.wire == 1)
    assert np.count_nonzero(result.wire == 1) == pytest.approx(along_overlap, abs=3)
    assert np.all(np.diff(result.chainage_m[result.wire == 0]) > 0.0)


def test_share_within_tolerance_is_what_the_noise_implies(line: Line) -> None:
    run_a, run_b = two_runs(line, sigma_a_mm=0.02, sigma_b_mm=0.03)
    result = compare_profiles(run_a, run_b)
    sigma = math.sqrt(0.02**2 + 2.0 / 3.0 * 0.03**2)
    assert result.rms_mm == pytest.approx(sigma, rel=0.05)
    assert abs(result.mean_mm) < 0.002
    assert result.share_within(0.1) == pytest.approx(expected_share(0.02, 0.03), abs=0.003)
    assert result.share_within(0.05) == pytest.approx(math.erf(0.05 / sigma / 2**0.5), abs=0.01)
    assert result.p95_mm == pytest.approx(1.96 * sigma, rel=0.05)
    assert result.max_abs_mm < 6.0 * sigma


def test_paper_like_repeatability_about_90_percent(line: Line) -> None:
    # noise of 0.045 mm per run: the difference's σ 0.058 mm, 91.5 % within 0.1 mm
    run_a, run_b = two_runs(line, sigma_a_mm=0.045, sigma_b_mm=0.045)
    result = compare_profiles(run_a, run_b)
    assert result.share_within() == pytest.approx(expected_share(0.045, 0.045), abs=0.01)
    assert 0.88 < result.share_within() < 0.95


def test_without_the_shift_the_hot_spots_disagree(line: Line) -> None:
    run_a, run_b = two_runs(line)
    shifted = compare_profiles(run_a, run_b)
    unshifted = compare_profiles(run_a, run_b, max_shift_m=0.0)
    assert unshifted.shift_m == 0.0
    # 0.32 m along a hot spot's flank (up to 0.5 mm/m) moves the thickness by up to 0.15 mm
    assert unshifted.share_within() < shifted.share_within() - 0.02
    assert unshifted.max_abs_mm > 0.15


def test_opposite_directions(line: Line) -> None:
    run_a, run_b = two_runs(line, offset_m=-0.433, decreasing=True)
    result = compare_profiles(run_a, run_b)
    assert set(result.wire_pairs) == {(0, 1), (1, 0)}
    assert result.shift_m == pytest.approx(-0.433, abs=0.005)
    assert result.share_within() == pytest.approx(expected_share(0.02, 0.03), abs=0.005)
    # and the other way round: A and B swap, the shift changes its sign
    swapped = compare_profiles(run_b, run_a)
    assert set(swapped.wire_pairs) == {(1, 0), (0, 1)}
    assert swapped.shift_m == pytest.approx(0.433, abs=0.005)
    assert swapped.mean_mm == pytest.approx(-result.mean_mm, abs=0.003)


def test_partial_run_and_an_unpaired_wire(line: Line) -> None:
    run_a, run_b = two_runs(line, start_m=START_M + 80.0, end_m=START_M + 180.0)
    # A also saw a wire B did not (a mistracked stretch 1.2 m beside the main one)
    far = (run_a.wire == 0) & (run_a.chainage_m > START_M + 100.0)
    far &= run_a.chainage_m < START_M + 120.0
    extra = RunProfile(
        np.concatenate([run_a.chainage_m, run_a.chainage_m[far]]),
        np.concatenate([run_a.wire, np.full(np.count_nonzero(far), 5)]),
        np.concatenate([run_a.stagger_mm, run_a.stagger_mm[far] + 1200.0]),
        np.concatenate([run_a.residual_thickness_mm, run_a.residual_thickness_mm[far]]),
    )
    result = compare_profiles(extra, run_b)
    assert set(result.wire_pairs) == {(0, 1), (1, 0)}
    assert result.shift_m == pytest.approx(0.317, abs=0.01)
    main = result.chainage_m[result.wire == 0]
    assert main.min() == pytest.approx(START_M + 80.0, abs=0.1)
    assert main.max() == pytest.approx(START_M + 180.0, abs=0.1)
    assert main.shape[0] == pytest.approx(100.0 / 0.0139, rel=0.01)
    assert result.share_within() == pytest.approx(expected_share(0.02, 0.03), abs=0.005)


def test_no_values_across_gaps_in_b(line: Line) -> None:
    run_a, run_b = two_runs(line)
    gap = (run_b.chainage_m > START_M + 50.0) & (run_b.chainage_m < START_M + 50.5)
    nan_gap = (run_b.chainage_m > START_M + 60.0) & (run_b.chainage_m < START_M + 60.05)
    thickness = run_b.residual_thickness_mm.copy()
    thickness[nan_gap] = np.nan  # a gap of 0.05 m: still interpolated
    holed = RunProfile(
        run_b.chainage_m[~gap], run_b.wire[~gap], run_b.stagger_mm[~gap], thickness[~gap]
    )
    result = compare_profiles(run_a, holed)
    c = result.chainage_m + result.shift_m  # in B's chainage
    assert not np.any((c > START_M + 50.0 + 0.02) & (c < START_M + 50.5 - 0.02))
    assert np.any((c > START_M + 60.0) & (c < START_M + 60.05))


def test_nan_thickness_in_a_is_skipped(line: Line) -> None:
    run_a, run_b = two_runs(line)
    thickness = run_a.residual_thickness_mm.copy()
    thickness[::3] = np.nan
    holed = RunProfile(run_a.chainage_m, run_a.wire, run_a.stagger_mm, thickness)
    result = compare_profiles(holed, run_b)
    assert np.all(np.isfinite(result.difference_mm))
    full = compare_profiles(run_a, run_b)
    assert result.points == pytest.approx(2.0 / 3.0 * full.points, rel=0.01)


def test_no_common_section_is_a_user_error(line: Line) -> None:
    run_a, run_b = two_runs(line)
    far = RunProfile(
        run_b.chainage_m + 1000.0, run_b.wire, run_b.stagger_mm, run_b.residual_thickness_mm
    )
    with pytest.raises(UserError, match="no section of line in common"):
        compare_profiles(run_a, far)


def test_no_matching_wire_is_a_user_error(line: Line) -> None:
    run_a, run_b = two_runs(line)
    beside = RunProfile(
        run_b.chainage_m, run_b.wire, run_b.stagger_mm + 600.0, run_b.residual_thickness_mm
    )
    with pytest.raises(UserError, match="no contact wire"):
        compare_profiles(run_a, beside)


def test_statistics_and_histogram_of_known_differences() -> None:
    d = np.array([-0.15, -0.05, -0.01, 0.0, 0.03, 0.09, 0.1, 0.25])
    result = Comparison(
        wire_pairs=((0, 0),),
        shift_m=0.0,
        stagger_rms_mm=1.0,
        chainage_m=np.arange(d.shape[0], dtype=np.float64),
        wire=np.zeros(d.shape[0], dtype=np.int64),
        residual_thickness_mm=np.full(d.shape[0], 12.0),
        difference_mm=d,
    )
    assert result.points == 8
    assert result.share_within(0.1) == pytest.approx(5 / 8)  # strictly less than 0.1
    assert result.rms_mm == pytest.approx(math.sqrt(np.mean(d**2)))
    assert result.max_abs_mm == pytest.approx(0.25)
    edges, counts = result.histogram(0.05)
    assert edges[0] == pytest.approx(-0.15) and edges[-1] == pytest.approx(0.25)
    assert np.allclose(np.diff(edges), 0.05)
    assert counts.sum() == 8
    assert list(counts) == [1, 0, 2, 2, 1, 1, 0, 1]  # [lo, hi)
    edges, counts = result.histogram(0.02, half_width_mm=0.1)
    assert edges[0] == pytest.approx(-0.1) and edges[-1] == pytest.approx(0.1)
    assert counts.sum() == 6  # -0.15 and 0.25 outside
    lines = result.summary_lines()
    assert lines[0].startswith("points compared") and "8" in lines[0]
    assert any("62.5 %" in text for text in lines)
    assert any(text.strip().startswith("< ") for text in lines)
    rows = lines[lines.index(next(t for t in lines if t.startswith("histogram"))) + 1 :]
    assert sum(int(row.split()[-3 if row.endswith("%") else -4]) for row in rows) == 8


def test_summary_of_a_comparison(line: Line) -> None:
    run_a, run_b = two_runs(line)
    result = compare_profiles(run_a, run_b)
    lines = result.summary_lines()
    text = "\n".join(lines)
    assert f"{result.points}" in lines[0]
    assert "+0.31" in text and "within ±0.10 mm" in text
    rows = [row for row in lines if " .. " in row]
    assert len(rows) == 20  # ±0.2 mm (twice the tolerance) in bins of 0.02 mm
    counts = [int(row.split()[3]) for row in rows]
    assert sum(counts[5:15]) == pytest.approx(result.share_within() * result.points, abs=1)
    assert sum(counts) == np.count_nonzero(np.abs(result.difference_mm) <= 0.2)
