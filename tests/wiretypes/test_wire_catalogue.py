"""The built-in catalogue as the registry and the CLI show it."""

from __future__ import annotations

from pathlib import Path

import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.plugins import PluginRegistry

EN_50149 = {"AC-80": 10.60, "AC-100": 12.00, "AC-107": 12.30, "AC-120": 13.20, "AC-150": 14.80}
# size -> (A, B, calculated area, names); reference/wire-profiles.md
TB_T_2809 = {
    85: (10.80, 10.76, 86.0, ["CTA85"]),
    110: (12.34, 12.34, 111.0, ["CTA110"]),
    120: (12.90, 12.90, 121.0, ["CTA120", "CTAH120", "CTMH120"]),
    150: (14.40, 14.10, 151.0, ["CTA150", "CTAH150", "CTMH150"]),
}


@pytest.fixture(scope="module")
def registry() -> PluginRegistry:
    return PluginRegistry()


def test_registry_finds_every_builtin_type_without_errors(registry: PluginRegistry) -> None:
    wires = registry.wire_types()
    expected = set(EN_50149) | {n for *_, names in TB_T_2809.values() for n in names}
    assert expected <= set(wires)
    assert registry.errors == []
    assert {registry.owner("wire type", name) for name in expected} == {"wiretypes"}


def test_en_50149_profiles(registry: PluginRegistry) -> None:
    wires = registry.wire_types()
    for name, diameter in EN_50149.items():
        wire = wires[name]
        assert (wire.height_mm, wire.width_mm) == (diameter, diameter)
        assert wire.area_mm2 == wire.nominal_area_mm2 == float(name.removeprefix("AC-"))
        assert wire.standard.startswith("EN 50149")
        assert not wire.legacy
        assert wire.source


def test_tb_t_2809_profiles_same_geometry_per_size(registry: PluginRegistry) -> None:
    wires = registry.wire_types()
    for size, (height, width, area, names) in TB_T_2809.items():
        for name in names:
            wire = wires[name]
            assert (wire.height_mm, wire.width_mm, wire.area_mm2) == (height, width, area)
            assert wire.nominal_area_mm2 == size
            assert wire.legacy == (size in (85, 110)), name
            assert wire.standard.startswith("TB/T 2809")
            assert wire.source


def test_cli_lists_them_in_size_order() -> None:
    result = CliRunner().invoke(cli, ["wire-types"])
    assert result.exit_code == 0, result.output
    names = [line.split()[0] for line in result.output.splitlines()[1:]]
    assert names.index("AC-80") < names.index("AC-100") < names.index("AC-150")
    (cta110,) = [line for line in result.output.splitlines() if line.startswith("CTA110 ")]
    assert cta110.endswith("wiretypes (legacy)")


def test_cli_shows_one_type_with_a_policy() -> None:
    result = CliRunner().invoke(cli, ["wire-types", "AC-120", "--policy", "db-ril-997"])
    assert result.exit_code == 0, result.output
    out = result.output
    assert "AC-120: EN 50149:2012; plugin wiretypes" in out
    assert "height A 13.20 mm, width B 13.20 mm" in out
    assert "policy db-ril-997" in out
    rows = [
        line.split() for line in out.splitlines() if line.strip().startswith(("urgent", "crit"))
    ]
    assert [(row[0], row[1], row[2]) for row in rows] == [
        ("urgent", "local", "10.144"),
        ("critical", "local", "10.000"),
    ]


def test_cli_uses_the_configs_policy(tmp_path: Path) -> None:
    config = tmp_path / "config.toml"
    config.write_text('[limits]\npolicy = "china-maintenance-rules"\n')
    result = CliRunner().invoke(cli, ["--config", str(config), "wire-types", "CTA120"])
    assert result.exit_code == 0, result.output
    assert "anchor_section_average" in result.output


def test_cli_unknown_wire_type_is_one_line_listing_known() -> None:
    result = CliRunner().invoke(cli, ["wire-types", "CTA121"])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1
    assert "unknown wire type 'CTA121' (known: AC-80, AC-100," in lines[0]
    assert "CTMH150" in lines[0]


def test_cli_unknown_policy_is_one_line_listing_known() -> None:
    result = CliRunner().invoke(cli, ["wire-types", "CTA120", "--policy", "db"])
    assert result.exit_code == 1
    lines = result.output.strip().splitlines()
    assert len(lines) == 1
    assert "unknown policy 'db' (known: china-maintenance-rules, db-ril-997," in lines[0]


def test_cli_policy_needs_a_wire_type() -> None:
    result = CliRunner().invoke(cli, ["wire-types", "--policy", "db-ril-997"])
    assert result.exit_code == 2
