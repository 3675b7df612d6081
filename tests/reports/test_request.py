"""A reporter's options are bounded: a value outside its range is refused in one line naming
the option, the value and the range, before any work."""

from __future__ import annotations

from pathlib import Path

import pytest

from catenary.config import Settings
from catenary.errors import UserError
from catenary.plugins import PluginRegistry, ReportRequest
from catenary_reports import repeatability, run_report
from catenary_reports.request import Option, parse_request

REPORTERS = {"run": (run_report.OPTIONS, 1), "repeatability": (repeatability.OPTIONS, 2)}
CASES = [
    (reporter, key, option, runs)
    for reporter, (options, runs) in REPORTERS.items()
    for key, option in options.items()
]


def request(tmp_path: Path, runs: int, **options: str) -> ReportRequest:
    settings = Settings(database_url="sqlite://", data_dir=tmp_path)
    registry = PluginRegistry(autoload=False)
    return ReportRequest(settings, registry, runs=("1", "2")[:runs], options=options)


@pytest.mark.parametrize(("reporter", "key", "option", "runs"), CASES)
def test_every_numeric_option_is_refused_outside_its_bounds(
    tmp_path: Path, reporter: str, key: str, option: Option, runs: int
) -> None:
    options = REPORTERS[reporter][0]
    for value in (option.low, option.default, option.high):
        raw = request(tmp_path, runs, **{key: repr(value)})
        parsed = parse_request(reporter, raw, runs=(runs, runs), options=options)
        assert parsed.options[key] == value
    low, high = f"{option.low:.15g}", f"{option.high:.15g}"
    for text in (repr(option.low - 1e-6), repr(option.high * 1.01 + 1), "nan", "inf", "x"):
        raw = request(tmp_path, runs, **{key: text})
        with pytest.raises(UserError) as caught:
            parse_request(reporter, raw, runs=(runs, runs), options=options)
        assert str(caught.value) == (
            f"reporter {reporter!r}: option {key} = {text!r} is outside {low} to {high} "
            f"{option.unit}"
        )
