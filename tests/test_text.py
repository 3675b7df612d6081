"""Control characters: refused in identifiers, escaped on the terminal."""

from __future__ import annotations

import pytest

from catenary.text import control_character_problem, printable


def test_printable_escapes_c0_del_and_c1_only() -> None:
    assert (
        printable("M1\x1b]0;x\x07\r\n\t\x7f\x9b é ü €")
        == "M1\\x1b]0;x\\x07\\r\\n\\t\\x7f\\x9b é ü €"
    )


@pytest.mark.parametrize("value", ["L1", "Strecke 6100 Süd", "M-12/3 ä"])
def test_printable_identifiers_have_no_problem(value: str) -> None:
    assert control_character_problem("line", value) is None
    assert printable(value) == value
