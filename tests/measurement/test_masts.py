"""The mast register CSV: masts per line and track, and one-line errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from catenary.domain import CODE_LENGTH
from catenary.errors import FormatError, UserError
from catenary.measurement.masts import read_register

WIRES = {"CTA120", "AC-100"}


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "masts.csv"
    path.write_text(text, encoding="utf-8")
    return path


def test_masts_sorted_by_chainage_per_line_and_track(tmp_path: Path):
    path = write(
        tmp_path,
        "line,track,mast,chainage_m,wire_type,design_stagger_mm,note\n"
        "L1,1,M2,1050.5,CTA120,-200,x\n"
        "L1,1,M1,1000.0,CTA120,,\n"
        "L1,2,N1,1000.0,AC-100,,\n",
    )
    register = read_register(path, WIRES)
    track = register.track("L1", "1")
    assert track.mast == ("M1", "M2") and track.span_name(0) == ("M1", "M2")
    np.testing.assert_allclose(track.chainage_m, [1000.0, 1050.5])
    assert np.isnan(track.design_stagger_mm[0]) and track.design_stagger_mm[1] == -200.0
    with pytest.raises(UserError, match="no masts for line 'L1' track '2'"):
        register.track("L1", "2")  # one mast is no span


def test_the_optional_numeric_columns_are_read_with_their_masts(tmp_path: Path):
    path = write(
        tmp_path,
        "line,track,mast,chainage_m,wire_type,design_height_mm,line_speed_kmh,latitude,longitude\n"
        "L1,1,M2,1050,CTA120,5300,160,48.1372,11.5756\n"
        "L1,1,M1,1000,CTA120,,200,,\n",
    )
    track = read_register(path, WIRES).track("L1", "1")
    assert track.mast == ("M1", "M2")
    for name, values in [
        ("design_height_mm", [np.nan, 5300.0]),
        ("line_speed_kmh", [200.0, 160.0]),
        ("latitude", [np.nan, 48.1372]),
        ("longitude", [np.nan, 11.5756]),
    ]:
        np.testing.assert_array_equal(getattr(track, name), values)
    plain = read_register(
        write(tmp_path, "line,track,mast,chainage_m,wire_type\nL1,1,M1,0,CTA120\n")
    )
    only = plain.tracks[("L1", "1")]
    assert only.design_height_mm is None and only.latitude is None  # no such column


OPTIONAL = (
    "line,track,mast,chainage_m,wire_type,design_height_mm,line_speed_kmh,latitude,longitude\n"
)


@pytest.mark.parametrize(
    ("row", "message"),
    [
        ("L1,1,M1,0,CTA120,-5,,,", "row 2: design_height_mm = '-5' is outside 0 to 10000"),
        ("L1,1,M1,0,CTA120,,0,,", "row 2: line_speed_kmh = '0' is outside 0 to 500"),
        ("L1,1,M1,0,CTA120,,,91,10", "row 2: latitude = '91' is outside -90 to 90"),
        ("L1,1,M1,0,CTA120,,,45,181", "row 2: longitude = '181' is outside -180 to 180"),
        ("L1,1,M1,0,CTA120,,,45,", "row 2: give latitude and longitude together"),
        ("L1,1,M1,0,CTA120,5.3k,,,", "row 2: design_height_mm = '5.3k' is not a finite number"),
    ],
)
def test_optional_numbers_out_of_their_range_are_refused(tmp_path: Path, row: str, message: str):
    path = write(tmp_path, OPTIONAL + row + "\n")
    with pytest.raises(FormatError, match=message):
        read_register(path, WIRES)


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("line,track,mast,wire_type\nL1,1,M1,CTA120\n", "no column 'chainage_m'"),
        (
            "line,track,mast,chainage_m,wire_type\nL1,1,M1,12.x,CTA120\n",
            "row 2: chainage_m = '12.x' is not a finite number",
        ),
        ("line,track,mast,chainage_m,wire_type\nL1,1,M1,nan,CTA120\n", "row 2: chainage_m"),
        ("line,track,mast,chainage_m,wire_type\nL1,1,,10,CTA120\n", "row 2: mast is empty"),
        (
            "line,track,mast,chainage_m,wire_type\nL1,1,M1,10,CTA999\n",
            "row 2: wire_type = 'CTA999' is not a known wire type",
        ),
        (
            "line,track,mast,chainage_m,wire_type\nL1,1,M1,10,CTA120\nL1,1,M1,60,CTA120\n",
            "mast 'M1' of line 'L1' track '1' twice",
        ),
        (
            "line,track,mast,chainage_m,wire_type\nL1,1,M1,10,CTA120\nL1,1,M2,10,CTA120\n",
            "masts 'M1' and 'M2' of line 'L1' track '1' at one chainage",
        ),
        ("line,track,mast,chainage_m,wire_type\n", "no masts"),
    ],
)
def test_bad_registers_are_refused_naming_the_file_row_and_field(
    tmp_path: Path, text: str, message: str
):
    path = write(tmp_path, text)
    with pytest.raises(FormatError, match=message) as error:
        read_register(path, WIRES)
    assert str(error.value).startswith(str(path)) and "\n" not in str(error.value)


@pytest.mark.parametrize("field", ["line", "track", "mast", "anchor_section"])
@pytest.mark.parametrize("control", ["\r", "\n", "\x1b[2J", "\x7f", "\x9b"])
def test_identifiers_with_control_characters_are_refused(tmp_path: Path, field: str, control: str):
    row = {"line": "L1", "track": "1", "mast": "M1", "anchor_section": "A1"}
    row[field] = f"X{control}Y"
    quoted = ",".join(f'"{value}"' for value in row.values())
    path = write(
        tmp_path,
        "line,track,mast,anchor_section,chainage_m,wire_type\n"
        f"{quoted},10,CTA120\nL1,1,M2,A1,60,CTA120\n",
    )
    with pytest.raises(FormatError) as error:
        read_register(path, WIRES)
    message = str(error.value)
    assert message.startswith(f"{path}: row ")  # the CSV line the record ends on
    assert message.endswith(
        f": {field} = {row[field]!r} holds a control character (identifiers are printable text)"
    )
    assert "\n" not in message and "\r" not in message and "\x1b" not in message


@pytest.mark.parametrize("field", ["line", "track", "mast", "anchor_section", "wire_type"])
def test_codes_longer_than_their_column_are_refused(tmp_path: Path, field: str):
    row = {"line": "L1", "track": "1", "mast": "M1", "anchor_section": "A1", "wire_type": "CTA120"}
    row[field] = "X" * (CODE_LENGTH + 1)
    path = write(
        tmp_path,
        "line,track,mast,anchor_section,wire_type,chainage_m\n"
        f"{','.join(row.values())},10\nL1,1,M2,A1,CTA120,60\n",
    )
    with pytest.raises(FormatError) as error:
        read_register(path, WIRES)
    assert str(error.value) == (
        f"{path}: row 2: {field} is {CODE_LENGTH + 1} characters long (at most {CODE_LENGTH})"
    )


def test_a_missing_register(tmp_path: Path):
    with pytest.raises(UserError, match="no such file"):
        read_register(tmp_path / "none.csv")
