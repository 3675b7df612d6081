"""Text from outside: control characters and lengths of identifiers, terminal escaping."""

from __future__ import annotations

import click
import pytest
from click.testing import CliRunner

from catenary.text import (
    control_character_problem,
    identifier_option,
    identifier_problem,
    length_problem,
    printable,
)


def test_printable_escapes_c0_del_and_c1_only() -> None:
    assert (
        printable("M1\x1b]0;x\x07\r\n\t\x7f\x9b é ü €")
        == "M1\\x1b]0;x\\x07\\r\\n\\t\\x7f\\x9b é ü €"
    )


@pytest.mark.parametrize("value", ["L1", "Strecke 6100 Süd", "M-12/3 ä"])
def test_printable_identifiers_have_no_problem(value: str) -> None:
    assert control_character_problem("line", value) is None
    assert printable(value) == value


def test_length_problem_counts_characters_not_bytes() -> None:
    assert length_problem("mast", "ü" * 32, 32) is None
    assert length_problem("mast", "M" * 33, 32) == "mast is 33 characters long (at most 32)"


def test_an_identifier_too_long_is_refused_without_repeating_it() -> None:
    assert identifier_problem("--by", "\x1b" * 300, 200) == (
        "--by is 300 characters long (at most 200)"
    )
    assert identifier_problem("--by", "a\x1b", 200) == (
        "--by = 'a\\x1b' holds a control character (identifiers are printable text)"
    )
    assert identifier_problem("--by", "a" * 200, 200) is None


def test_identifier_option_names_the_option() -> None:
    @click.command()
    @click.option("--line", callback=identifier_option(4))
    def command(line: str | None) -> None:
        click.echo(f"line {line}")

    assert CliRunner().invoke(command, ["--line", "L100"]).output == "line L100\n"
    assert CliRunner().invoke(command, []).output == "line None\n"
    refused = CliRunner().invoke(command, ["--line", "L1000"])
    assert refused.exit_code != 0
    assert str(refused.exception) == "--line is 5 characters long (at most 4)"
