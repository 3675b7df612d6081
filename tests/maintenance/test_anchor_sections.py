"""The mast register's anchor sections: read from the CSV, stored on the masts."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import Engine, select

from catenary.errors import FormatError
from catenary.measurement.masts import read_register
from catenary.storage.database import session_scope
from catenary.storage.models import Mast
from catenary.storage.runs import register_track, track_masts

HEADER = "line,track,mast,chainage_m,wire_type,anchor_section\n"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "masts.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_sections_are_read_per_mast(tmp_path: Path) -> None:
    path = write(
        tmp_path,
        HEADER + "L1,1,M3,1100,CTA120,B\nL1,1,M1,1000,CTA120,A\nL1,1,M2,1050,CTA120,A\n"
        "L1,1,M4,1150,CTA120,\n",
    )
    track = read_register(path).track("L1", "1")
    assert track.mast == ("M1", "M2", "M3", "M4")
    assert track.anchor_section == ("A", "A", "B", None)
    plain = write(tmp_path, "line,track,mast,chainage_m,wire_type\nL1,1,M1,1000,CTA120\n")
    assert read_register(plain).tracks[("L1", "1")].anchor_section is None


def test_a_section_whose_masts_do_not_follow_one_another_is_refused(tmp_path: Path) -> None:
    path = write(
        tmp_path, HEADER + "L1,1,M1,1000,CTA120,A\nL1,1,M2,1050,CTA120,B\nL1,1,M3,1100,CTA120,A\n"
    )
    with pytest.raises(FormatError, match="mast 'M3' of line 'L1' track '1': anchor_section 'A'"):
        read_register(path)
    gap = write(
        tmp_path, HEADER + "L1,1,M1,1000,CTA120,A\nL1,1,M2,1050,CTA120,\nL1,1,M3,1100,CTA120,A\n"
    )
    with pytest.raises(FormatError, match="resumes after mast 'M2'") as error:
        read_register(gap)
    assert "\n" not in str(error.value) and str(error.value).startswith(str(gap))


def test_sections_are_stored_and_kept_by_a_register_without_them(
    engine: Engine, tmp_path: Path
) -> None:
    with_sections = read_register(
        write(tmp_path, HEADER + "L1,1,M1,1000,CTA120,A\nL1,1,M2,1050,CTA120,A\n")
    )
    (tmp_path / "plain").mkdir()
    without = read_register(
        write(tmp_path / "plain", "line,track,mast,chainage_m,wire_type\nL1,1,M1,1000,CTA120\n")
    )
    renamed = read_register(
        write(tmp_path, HEADER + "L1,1,M1,1000,CTA120,A1\nL1,1,M2,1050,CTA120,\n")
    )
    with session_scope(engine) as session:
        _, track = register_track(session, "L1", "1")
        assert track_masts(session, track, with_sections.track("L1", "1")) == 2
        assert track_masts(session, track, without.tracks[("L1", "1")]) == 0  # kept
        sections = dict(session.execute(select(Mast.code, Mast.anchor_section)).all())
        assert sections == {"M1": "A", "M2": "A"}
        assert track_masts(session, track, renamed.track("L1", "1")) == 2
        sections = dict(session.execute(select(Mast.code, Mast.anchor_section)).all())
        assert sections == {"M1": "A1", "M2": None}
