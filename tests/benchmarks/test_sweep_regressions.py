"""Sweep scenes that failed a target, cut to the stretch that failed: each must now meet
every target there (issue 14: a failing scene keeps its seed and becomes a regression test).

Rerun one by hand with ``benchmarks/sweep.py --seed S --scene K --scans FIRST STOP``.
"""

from __future__ import annotations

from types import ModuleType
from typing import Any

import pytest


def stretch(sweep: ModuleType, seed: int, scene: int, scans: tuple[int, int]) -> dict[str, Any]:
    """The sweep's row of a scene's stretch, which ran without an error."""
    row: dict[str, Any] = sweep.run_scenario(sweep.draw(seed, scene), scans)
    assert row["error"] == ""
    return row


FIXED = [
    # white daylight, new wire, five 8k cameras: its messenger in line with it in one camera
    # merged the two silhouettes, which moved the wire's axis 2-3 mm and, taken by the
    # messenger, lost the wire for 45-53 scans at a time (worst height 13.8 mm, recall 97 %)
    pytest.param(0, 17, (3000, 3800), id="messenger-in-line"),
    # white daylight, new wire, six 8k cameras: a dropper clamp's silhouette located the
    # wire 4.5-11.6 mm too high
    pytest.param(0, 5, (2600, 3400), id="dropper-clamp"),
    # night, two 8k cameras: every pairing of the two images intersects, and the ghosts of
    # one camera's wire with the other's messenger were reported (recall 0 %)
    pytest.param(0, 29, (0, 1500), id="two-cameras"),
    # white daylight, five 16k cameras, 5 mm faces: the silhouette's blurred edges reached
    # past the face search's guard and were taken for the face's, whose own edges were then
    # not found: worn wire read as new (0.36 mm of thickness RMS)
    pytest.param(0, 20, (12500, 13300), id="face-between-blurred-silhouette-edges-16k"),
    # white daylight, six 16k cameras, 1 mm faces: the same (height 11.7 mm off in some rows,
    # recall 96 %)
    pytest.param(0, 41, (8000, 8800), id="narrow-faces-between-blurred-edges-16k"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "scene", "scans"), FIXED)
def test_a_stretch_that_failed_meets_every_target(
    sweep: ModuleType, seed: int, scene: int, scans: tuple[int, int]
) -> None:
    row = stretch(sweep, seed, scene, scans)
    assert row["fails"] == "", sweep.row_line(row)


GHOSTS = [
    # white daylight, four 16k cameras with an overlap: rays of different wires that three
    # cameras paired made a wire 255 mm beneath the contact wire (14 rows of this stretch,
    # recall 79 %); the fourth camera's line shows only sky there. The stretch still fails
    # the thickness worst (0.21 mm, 1 mm faces), which is not this test's matter.
    pytest.param(0, 59, (4800, 5300), id="ghost-of-three-cameras-of-four"),
]


@pytest.mark.slow
@pytest.mark.parametrize(("seed", "scene", "scans"), GHOSTS)
def test_a_stretch_that_had_a_ghost_has_no_false_wire(
    sweep: ModuleType, seed: int, scene: int, scans: tuple[int, int]
) -> None:
    row = stretch(sweep, seed, scene, scans)
    assert row["false_wires"] == 0 and row["false_rows"] == 0, sweep.row_line(row)
    assert row["recall"] > 0.99, sweep.row_line(row)


@pytest.mark.slow
def test_a_turnout_s_crossing_reports_each_wire_s_face_seen_alone(sweep: ModuleType) -> None:
    # day behind the filter, five 4k cameras, 4 mm faces, wires crossing at 3°: within 20 mm
    # of each other the matching found one wire by its face in nearly every scan, and kept
    # one of two faces 11-19 mm apart; every point there was uncertain (1.7 % of this
    # stretch's rows, recall 94.8 %). Where the wires touch the cameras see one image of
    # both: recall cannot reach 99.5 % on so short a stretch, the other targets are met.
    row = stretch(sweep, 0, 6, (5300, 5900))
    assert row["recall"] > 0.98 and row["uncertain_share"] < 0.005, sweep.row_line(row)
    assert row["fails"] == "recall", sweep.row_line(row)


@pytest.mark.slow
def test_a_messenger_beside_a_lit_wire_leaves_the_wire_found(sweep: ModuleType) -> None:
    # day behind the filter, five 16k cameras, 3 mm faces: in one camera the messenger lies
    # 18 px of sky beside the wire's dark side, and the wire's lit face, taken for the sky
    # beside them, made the two one dark silhouette split at a face; the wire's candidate
    # reached over the messenger or was lost (recall 97.3 % on this stretch). The stretch
    # still misses scans elsewhere in other cameras and one row is 3 mm high.
    row = stretch(sweep, 0, 42, (1550, 1800))
    assert row["recall"] > 0.985 and row["false_rows"] == 0, sweep.row_line(row)
