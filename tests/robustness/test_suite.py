"""The suite's own helpers refuse what they must."""

from __future__ import annotations

import pytest

from .conftest import assert_refused, catenary


def test_an_unknown_command_is_refused_in_one_line() -> None:
    assert_refused(catenary("no-such-command"), "no-such-command")


def test_every_test_here_is_marked(request: pytest.FixtureRequest) -> None:
    assert request.node.get_closest_marker("robustness") is not None
