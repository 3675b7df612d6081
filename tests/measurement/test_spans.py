"""Span layout and per span and wire statistics gathered block by block."""

from __future__ import annotations

import math

import numpy as np

from catenary.measurement.spans import SpanAccumulator, SpanLayout


def test_statistics_in_blocks_equal_those_of_the_whole():
    rng = np.random.default_rng(4)
    m = 5000
    span = rng.integers(-1, 4, m)
    wire = rng.integers(0, 2, m)
    chainage = np.sort(rng.uniform(0, 200, m))
    thickness = rng.uniform(9.0, 12.9, m)
    thickness[rng.random(m) < 0.05] = np.nan
    height = rng.normal(5300, 20, m)
    stagger = rng.normal(0, 150, m)
    accumulator = SpanAccumulator()
    for part in np.array_split(np.arange(m), 7):
        accumulator.add(
            span[part], wire[part], chainage[part], thickness[part], height[part], stagger[part]
        )
    results = accumulator.results()
    assert [(r.span, r.wire) for r in results] == sorted(
        {(s, w) for s, w in zip(span.tolist(), wire.tolist(), strict=True) if s >= 0}
    )
    for r in results:
        rows = (span == r.span) & (wire == r.wire)
        h = thickness[rows]
        assert r.samples == np.count_nonzero(rows)
        assert r.thickness_samples == np.count_nonzero(np.isfinite(h))
        assert r.min_residual_thickness_mm == np.nanmin(h)
        assert r.min_at_chainage_m == chainage[rows][np.nanargmin(h)]
        assert math.isclose(r.mean_residual_thickness_mm, np.nanmean(h), rel_tol=1e-12)
        assert (r.height_min_mm, r.height_max_mm) == (height[rows].min(), height[rows].max())
        assert (r.stagger_min_mm, r.stagger_max_mm) == (stagger[rows].min(), stagger[rows].max())


def test_a_span_without_any_thickness_has_none():
    accumulator = SpanAccumulator()
    accumulator.add([0, 0], [1, 1], [5.0, 6.0], [np.nan, np.nan], [5300.0, 5301.0], [1.0, 2.0])
    (r,) = accumulator.results()
    assert r.samples == 2 and r.thickness_samples == 0
    assert math.isnan(r.min_residual_thickness_mm) and math.isnan(r.min_at_chainage_m)


def test_spans_between_turning_points_closed_by_the_run_ends():
    layout = SpanLayout.from_turning_points([1049.5, 1000.2, 1100.0, 1200.0], (1150.0, 980.0))
    np.testing.assert_allclose(layout.boundaries_m[:4], [980.0, 1000.2, 1049.5, 1100.0])
    assert layout.boundaries_m[-1] > 1150.0 and layout.spans == 4
    np.testing.assert_array_equal(
        layout.index([979.0, 980.0, 1000.1, 1000.2, 1120.0, 1150.0, 1151.0, np.nan]),
        [-1, 0, 0, 1, 3, 3, -1, -1],
    )
    assert layout.mast_from == (None,) * 4


def test_the_values_at_a_mast_are_the_medians_within_a_metre_of_it_over_blocks():
    # masts at 0, 50 and 100 m; one wire whose stagger is a V with its tip at the middle mast
    # (200 mm there, falling 10 mm/m either side) and height 5500 + chainage mm; samples every
    # 0.1 m in three blocks that split the samples near the middle mast
    chainage = np.arange(0.05, 100.0, 0.1)
    stagger = 200.0 - 10.0 * np.abs(chainage - 50.0)
    height = 5500.0 + chainage
    span = (chainage >= 50.0).astype(np.int64)
    accumulator = SpanAccumulator(np.array([0.0, 50.0, 100.0]))
    for block in np.array_split(np.arange(chainage.shape[0]), [495, 503]):
        accumulator.add(
            span[block], np.zeros(block.shape[0]), chainage[block],
            np.full(block.shape[0], 10.0), height[block], stagger[block],
        )  # fmt: skip
    first, second = accumulator.results()
    # within ±1 m: the V's median lies half a metre down it (5 mm), the height's at the mast
    assert first.height_at_end_mm == second.height_at_start_mm
    assert math.isclose(second.height_at_start_mm, 5550.0, abs_tol=0.1)
    assert math.isclose(second.stagger_at_start_mm, 195.0, abs_tol=0.6)
    # the run's end masts: only the metre inside the run
    assert math.isclose(first.height_at_start_mm, 5500.5, abs_tol=0.1)
    assert math.isclose(second.height_at_end_mm, 5599.5, abs_tol=0.1)
    # without the masts' chainages: no values at them
    plain = SpanAccumulator()
    plain.add(span, np.zeros(span.shape[0]), chainage, np.full(span.shape[0], 10.0), height,
              stagger)  # fmt: skip
    assert all(math.isnan(s.stagger_at_start_mm) for s in plain.results())
