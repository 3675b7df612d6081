"""The span page: history table and chart, wear rate, forecasts, latest run, alerts and
maintenance actions, for a signed-in person."""

from __future__ import annotations

import re
from datetime import datetime

import pytest

from catenary.web.api.spans import HistoryRunOut, WireHistoryOut
from catenary.web.pages.spans import history_chart
from tests.web.test_api import L1_1, WORN_MM, Web, api

__all__ = ["api"]


def _page(api: Web, **query: object) -> str:
    answer = api.client("vera").get("/span", params=L1_1 | query)
    assert answer.status_code == 200, answer.text
    return answer.text


def test_the_span_page_shows_its_history_forecast_alerts_and_actions(api: Web) -> None:
    html = _page(api, mast="M03")
    assert "<h1>Span from mast M03</h1>" in html
    assert "Wire position 0" in html and "CTA120" in html
    # one table row per run, the minimum to 0.01 mm
    runs = re.search(r'<table class="span-table runs">(.*?)</table>', html, re.S)
    assert runs is not None
    assert re.findall(r'<td class="num">(\d+\.\d\d)</td><td class="num">', runs.group(1)) == [
        f"{v:.2f}" for v in WORN_MM
    ]
    assert "Wear rate 0.410 mm/year" in html
    assert html.count('<span class="level urgent">urgent</span>') >= 2  # forecast and alert
    # the chart: four points and a dashed line per limit
    svg = re.search(r"<svg class=\"span-chart\".*?</svg>", html, re.S)
    assert svg is not None and svg.group(0).count("<circle") == 4
    assert 'class="limit urgent"' in svg.group(0) and 'class="limit critical"' in svg.group(0)
    assert svg.group(0).count('class="forecast"') == 1  # to the first limit's date
    assert "10.80" in html and "1+162.5" in html  # the latest run: minimum and where
    assert 'href="/alerts?line=L1&amp;track=1&amp;status=all"' in html
    assert "No maintenance action recorded" in html


def test_a_repair_shows_on_the_page(api: Web) -> None:
    body = {
        "line": "L1", "track": "1", "kind": "spliced", "from_mast": "M03", "to_mast": "M04",
        "performed_at": "2023-06-01T08:00:00Z", "note": "splice <b>at</b> 1175 m",
    }  # fmt: skip
    assert api.api("pat").post("/api/v1/maintenance-actions", json=body).status_code == 201
    html = _page(api, mast="M03", wire_position=0)
    assert "splice &lt;b&gt;at&lt;/b&gt; 1175 m" in html  # escaped
    assert html.count("before the last repair") == 4
    assert "needs 3 runs since the last repair, has 0" in html


@pytest.mark.parametrize(
    ("query", "status", "words"),
    [
        ({"mast": "M99"}, 400, "no mast &#39;M99&#39;"),
        ({}, 400, "give mast"),
        ({"from_m": 5, "to_m": 1}, 400, "must not exceed"),
        ({"mast": "M03", "wire_position": "x"}, 400, "wire_position"),
    ],
)
def test_bad_span_addresses_are_an_error_page(
    api: Web,
    query: dict[str, object],
    status: int,
    words: str,
) -> None:
    answer = api.client("vera").get("/span", params=L1_1 | query)
    assert answer.status_code == status and words in answer.text
    assert "Traceback" not in answer.text


def test_the_span_page_needs_a_session(api: Web) -> None:
    answer = api.anonymous().get("/span", params=L1_1 | {"mast": "M03"})
    assert answer.status_code == 303 and answer.headers["location"].startswith("/sign-in")


def test_the_chart_puts_a_thinner_wire_lower() -> None:
    runs = [
        HistoryRunOut(
            run_id=k, started_at=datetime(2020 + k, 6, 1), direction="increasing",
            min_residual_thickness_mm=mm, mean_residual_thickness_mm=mm + 0.5,
            height_min_mm=5280.0, height_max_mm=5320.0, stagger_min_mm=-200.0,
            stagger_max_mm=200.0, since_repair=True,
        )
        for k, mm in enumerate((12.0, 11.0))
    ]  # fmt: skip
    wire = WireHistoryOut(
        wire_position=0, mast_from="M1", mast_to="M2", start_chainage_m=0.0,
        end_chainage_m=50.0, wire_type="CTA120", runs=runs, fitted_runs=2,
        wear_rate_mm_per_year=None, wear_rate_low_mm_per_year=None,
        wear_rate_high_mm_per_year=None, forecasts=[],
    )  # fmt: skip
    chart = history_chart([wire], width=600, height=300)
    (first, second) = chart.series[0].points
    assert second[0] > first[0] and second[1] > first[1]  # later: right; thinner: lower
    assert all(
        chart.left <= x <= chart.width and 0 <= y <= chart.bottom for x, y in (first, second)
    )
    assert [label for _, label in chart.x_ticks] == ["2021"]
