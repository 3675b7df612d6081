"""Span-wire histories from span rows: wire positions, repairs, anchor-section averages."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from catenary.maintenance.history import (
    Repairs,
    SpanRows,
    section_measurements,
    span_histories,
    wire_positions,
)


def rows(**columns: Any) -> SpanRows:
    """Rows with defaults: one wire per span, masts ``span`` to ``span + 1``, 50 m spans."""
    span = np.asarray(columns["span"], dtype=np.int64)
    m = span.shape[0]
    defaults: dict[str, Any] = {
        "measurement_id": np.arange(m),
        "wire": np.zeros(m, dtype=np.int64),
        "mast_from": span,
        "mast_to": span + 1,
        "start_m": 1000.0 + 50.0 * span,
        "end_m": 1050.0 + 50.0 * span,
        "min_thickness_mm": np.full(m, 12.0),
        "mean_thickness_mm": np.full(m, 12.5),
        "samples": np.full(m, 1000),
        "stagger_sum_mm": np.zeros(m),
        "wire_type": np.zeros(m, dtype=np.int64),
        "direction": np.ones(m),
    }
    defaults.update(columns)
    return SpanRows(**{k: np.asarray(v) for k, v in defaults.items()})


def test_positions_count_from_the_left_looking_towards_increasing_chainage() -> None:
    run = np.array([1, 1, 1, 2, 2, 2])
    span = np.array([7, 7, 8, 7, 7, 8])
    line_stagger = np.array([300.0, -300.0, 0.0, -300.0, 300.0, 10.0])
    wire = np.array([0, 1, 1, 0, 1, 0])
    assert wire_positions(run, span, line_stagger, wire).tolist() == [1, 0, 0, 0, 1, 0]
    # equal staggers: by the run's wire number
    assert wire_positions(run[:2], span[:2], np.zeros(2), np.array([1, 0])).tolist() == [1, 0]


def test_histories_follow_spans_and_positions_across_runs_and_directions() -> None:
    # span 4 an overlap; run 2 the other way: wire numbers swapped, stagger signs flipped
    r = rows(
        run_id=[1, 1, 1, 2, 2, 2],
        span=[3, 4, 4, 3, 4, 4],
        wire=[0, 0, 1, 1, 1, 0],
        stagger_sum_mm=[0.0, -300.0, 300.0, 0.0, 300.0, -300.0],
        direction=[1.0, 1.0, 1.0, -1.0, -1.0, -1.0],
        min_thickness_mm=[11.0, 10.0, 9.0, 10.8, 9.9, 8.8],
        time_years=[20.0, 20.0, 20.0, 21.0, 21.0, 21.0],
    )
    h = span_histories(r, Repairs.none())
    assert h.histories == 3
    assert h.row_history[[1, 4]].tolist() == [h.row_history[1]] * 2  # left wire of span 4
    assert h.row_history[[2, 5]].tolist() == [h.row_history[2]] * 2  # right wire
    right = h.row_history[2]
    assert h.position[right] == 1 and h.latest[right] == 5
    assert h.fit.wear_rate_mm_per_year[right] == pytest.approx(0.2)


def test_without_a_register_a_span_is_its_chainages() -> None:
    r = rows(
        run_id=[1, 2, 3],
        span=[0, 0, 0],
        mast_from=[-1, -1, -1],
        mast_to=[-1, -1, -1],
        start_m=[1000.0, 1000.0, 1000.3],
        end_m=[1050.0, 1050.0, 1050.2],
        time_years=[20.0, 21.0, 22.0],
    )
    h = span_histories(r, Repairs.none())
    assert h.histories == 2 and h.row_history.tolist() == [0, 0, 1]
    assert h.mast_from.tolist() == [-1, -1]


def test_a_repair_restarts_the_history_of_the_spans_and_wire_it_touches() -> None:
    r = rows(
        run_id=[1, 1, 2, 2, 3, 3],
        span=[0, 1, 0, 1, 0, 1],
        time_years=[20.0, 20.0, 21.0, 21.0, 22.0, 22.0],
    )
    # span 0 (1000-1050 m) repaired at 21.5 on wire 0; a repair on wire 1 changes nothing
    repairs = Repairs(
        from_m=np.array([1010.0, 1000.0]),
        to_m=np.array([1011.0, 1100.0]),
        wire=np.array([0, 1]),
        time_years=np.array([21.5, 21.7]),
    )
    h = span_histories(r, repairs)
    first, second = h.row_history[4], h.row_history[1]  # spans 0 and 1
    assert h.row_history.tolist() == [-1, second, -1, second, first, second]
    assert h.fit.runs[first] == 1 and h.fit.runs[second] == 3
    assert h.repaired_years[first] == 21.5 and h.repaired_years[second] == -np.inf


def test_section_averages_weight_by_samples_and_need_the_whole_section() -> None:
    # masts 0-4: section 0 spans 0-3 (200 m); run 1 measures it all, run 2 half of it
    r = rows(
        run_id=[1, 1, 1, 1, 2, 2],
        span=[0, 1, 2, 3, 0, 1],
        mean_thickness_mm=[9.0, 10.0, 10.0, 10.0, 12.0, 12.0],
        samples=[3000, 1000, 1000, 1000, 1000, 1000],
        time_years=[20.0] * 4 + [21.0] * 2,
    )
    h = span_histories(r, Repairs.none())
    mast_section = np.array([0, 0, 0, 0, -1])
    found = section_measurements(r, h, mast_section, np.array([200.0]))
    assert found.run_id.tolist() == [1]  # run 2 covers half the section
    assert found.mean_thickness_mm[0] == pytest.approx((3 * 9.0 + 3 * 10.0) / 6)
    assert found.coverage[0] == 1.0 and found.wire_type[0] == 0
    mixed = rows(**{**r.__dict__, "wire_type": np.array([0, 1, 0, 0, 0, 0])})
    assert section_measurements(mixed, h, mast_section, np.array([200.0])).wire_type[0] == -2
