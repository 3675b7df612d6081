"""Text longer than the database column that keeps it is refused where it comes in, in one line
naming the option or file, the field, its length and the limit; nothing is stored (on
PostgreSQL it was a ``DataError`` traceback, on SQLite stored past the column's length)."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path
from typing import Any

import h5py
import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from catenary.domain import CODE_LENGTH, NAME_LENGTH
from catenary.storage.models import Alert

from ..conftest import SmallRun
from .conftest import assert_refused, catenary
from .hardening_support import row_counts


def _process(run: SmallRun, *extra: str | Path, rig: Path | None = None) -> list[str | Path]:
    return ["process", run.run, "--rig", rig or run.rig, "--masts", run.masts, *extra]


def _long_line_option(run: SmallRun, tmp_path: Path) -> list[str | Path]:
    return _process(run, "--line", "L" * 40)


def _long_line_in_the_run_file(run: SmallRun, tmp_path: Path) -> list[str | Path]:
    copy = tmp_path / "run.h5"
    shutil.copyfile(run.run, copy)
    with h5py.File(copy, "r+") as file:
        file.attrs["track"] = "T" * 40
    return ["process", copy, "--rig", run.rig, "--wire-type", "CTA120"]


def _long_mast_in_the_register(run: SmallRun, tmp_path: Path) -> list[str | Path]:
    register = tmp_path / "masts.csv"
    rows = run.masts.read_text().splitlines()
    line, track, _, rest = rows[2].split(",", 3)
    register.write_text("\n".join([*rows, f"{line},{track},{'M' * 10_000},{rest}"]) + "\n")
    return ["process", run.run, "--rig", run.rig, "--masts", register]


def _long_rig_name(run: SmallRun, tmp_path: Path) -> list[str | Path]:
    rig = tmp_path / f"{'r' * (NAME_LENGTH + 1)}.toml"
    shutil.copyfile(run.rig, rig)
    return _process(run, rig=rig)


def _long_vehicle_name(run: SmallRun, tmp_path: Path) -> list[str | Path]:
    rig = tmp_path / "rig.toml"
    text = run.rig.read_text()
    assert 'name = "demo-rig"' in text
    rig.write_text(text.replace('name = "demo-rig"', f'name = "{"v" * 300}"', 1))
    return _process(run, rig=rig)


CASES: dict[str, tuple[Callable[[SmallRun, Path], list[str | Path]], tuple[str, ...]]] = {
    "--line": (_long_line_option, ("--line", "40 characters", f"at most {CODE_LENGTH}")),
    "run file track": (
        _long_line_in_the_run_file,
        ("run.h5", "'track'", "40 characters", f"at most {CODE_LENGTH}", "--track"),
    ),
    "register mast": (
        _long_mast_in_the_register,
        ("masts.csv", "mast", "10000 characters", f"at most {CODE_LENGTH}"),
    ),
    "rig name": (_long_rig_name, (".toml", "name", "201 characters", f"at most {NAME_LENGTH}")),
    "vehicle name": (_long_vehicle_name, ("rig.toml", "name", "300 characters", "at most 200")),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_process_refuses_text_longer_than_its_column(
    case: str, small_run: SmallRun, engine: Engine, database_url: str, tmp_path: Path
) -> None:
    make, words = CASES[case]
    result = catenary("--db", database_url, *make(small_run, tmp_path), timeout=60)
    assert_refused(result, *words)
    assert not any(row_counts(engine).values())
    assert not list((tmp_path / "catenary-data").glob("samples/*"))


@pytest.fixture
def stored(engine: Engine, build: Any) -> int:
    """A run on line L100 track 1 with an open alert; its id."""
    with Session(engine) as session, session.begin():
        found = build.run(session)
        alert = build.alert(found.track, "key-1")
        session.add(alert)
        session.flush()
        return alert.id


def test_a_long_by_is_refused_and_nothing_changes(
    stored: int, engine: Engine, database_url: str
) -> None:
    before = row_counts(engine)
    by = "b" * (NAME_LENGTH + 100)
    record = ["maintenance", "record", "--line", "L100", "--track", "1", "--kind", "inspected"]
    for args in (
        [*record, "--from-m", "1000", "--to-m", "1050", "--by", by],
        ["alerts", "ack", str(stored), "--by", by],
        ["alerts", "resolve", str(stored), "--by", by],
    ):
        assert_refused(catenary("--db", database_url, *args), "--by", "300 characters", "200")
    assert row_counts(engine) == before
    with Session(engine) as session:
        alert = session.get(Alert, stored)
        assert alert is not None and alert.status == "open" and alert.acknowledged_by is None


def test_long_codes_given_to_look_ups_are_refused(engine: Engine, database_url: str) -> None:
    for args in (
        ["maintenance", "record", "--line", "L" * 33, "--track", "1"],
        ["alerts", "list", "--line", "L" * 33],
        ["report", "run", "--line", "L" * 33],
    ):
        assert_refused(catenary("--db", database_url, *args), "--line", "33 characters", "32")
