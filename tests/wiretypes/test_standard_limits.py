"""Alerts out of the box: each wire type's own standard limit when no policy is configured."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.config import Settings
from catenary.limits import STANDARD_POLICY, choose_policy, standard_policy, thresholds
from catenary.plugins import PluginRegistry
from catenary.wiretype import WireType


@pytest.fixture(scope="module")
def registry() -> PluginRegistry:
    return PluginRegistry()


def test_a_published_minimum_is_the_limit_else_30_percent(registry: PluginRegistry) -> None:
    wire_types = registry.wire_types()
    policy = standard_policy(wire_types)
    assert policy.name == STANDARD_POLICY
    # EN 50149 profiles with a published minimum (DB Ril 997, reference/wire-profiles.md)
    for name, minimum_mm in (("AC-80", 8.1), ("AC-100", 9.2), ("AC-120", 10.0)):
        (limit,) = thresholds(wire_types[name], policy)
        assert limit.residual_thickness_mm == pytest.approx(minimum_mm, abs=1e-9)
        assert limit.level == "critical"
    # the others: 30 % loss of cross-section (CTA120: 8.75 mm, reference/wire-profiles.md)
    (limit,) = thresholds(wire_types["CTA120"], policy)
    assert limit.worn_fraction == pytest.approx(0.30, abs=1e-9)
    assert limit.residual_thickness_mm == pytest.approx(8.75, abs=0.01)
    assert all(len(thresholds(wire, policy)) == 1 for wire in wire_types.values())


def test_the_configuration_still_chooses_the_policy(
    registry: PluginRegistry, tmp_path: Path
) -> None:
    presets, wire_types = registry.limit_policies(), registry.wire_types()
    bare = Settings(database_url="sqlite://", data_dir=tmp_path)
    chosen = choose_policy(bare, presets, wire_types=wire_types)
    assert chosen is not None and chosen.name == STANDARD_POLICY
    assert choose_policy(bare, presets) is None  # no wire types: nothing to evaluate with
    configured = replace(bare, sections={"limits": {"policy": "db-ril-997"}})
    chosen = choose_policy(configured, presets, wire_types=wire_types)
    assert chosen is not None and chosen.name == "db-ril-997"


def test_wire_types_name_says_which_standard_limit() -> None:
    result = CliRunner().invoke(cli, ["wire-types", "AC-120"])
    assert result.exit_code == 0, result.output
    assert "  standard limit: residual thickness 10 mm (published minimum)" in result.output
    assert f"policy {STANDARD_POLICY}: " in result.output
    result = CliRunner().invoke(cli, ["wire-types", "CTA120"])
    assert "standard limit: 30 % loss of cross-section (the manufacturers' rule" in result.output


def test_a_published_minimum_outside_the_profile_is_refused() -> None:
    with pytest.raises(ValueError, match=r"published minimum 5\.0 mm is outside its profile"):
        WireType("X", "s", 12.0, 12.0, 100.0, 100.0, published_min_mm=5.0)
