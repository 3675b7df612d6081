"""Strict configuration: every section of the config file is read by the core or declared by
a plugin (``catenary_config_sections``), every key is known, and a wrong one is refused in one
line naming the file, the section or key, and the nearest known name."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.config import load_settings
from catenary.errors import UserError
from catenary.plugins import CommandContext, ConfigSection, PluginRegistry, hookimpl


def _check_camera(table: Mapping[str, Any]) -> None:
    if not isinstance(table.get("exposure_us", 100), int):
        raise ValueError("exposure_us must be a whole number of\nmicroseconds")


class CameraPlugin:
    @hookimpl
    def catenary_config_sections(self) -> list[ConfigSection]:
        return [
            ConfigSection("camera", frozenset({"exposure_us", "gain_db"}), _check_camera),
            ConfigSection("cameras"),  # open: subsections named by the user
        ]


class GreedyPlugin:
    @hookimpl
    def catenary_config_sections(self) -> list[ConfigSection]:
        return [ConfigSection("database"), ConfigSection("scheduler"), ConfigSection("webcam")]


def registry(*plugins: tuple[str, object]) -> PluginRegistry:
    return PluginRegistry(autoload=False, plugins=plugins)


def check(tmp_path: Path, text: str, found: PluginRegistry) -> None:
    config = tmp_path / "site.toml"
    config.write_text(text)
    found.check_settings(load_settings(config_path=config))


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (
            '[databse]\nurl = "sqlite:///x"\n',
            "unknown section [databse] (did you mean [database]?)",
        ),
        ("[schedular]\n", "unknown section [schedular] (did you mean [scheduler]?)"),
        ("[camra]\ngain_db = 1\n", "unknown section [camra] (did you mean [camera]?)"),
        ("[zzz]\n", "unknown section [zzz] (known: [camera], [cameras], [database], "),
        ('url = "sqlite:///x"\n', "unknown top-level key 'url' (known: [camera]"),
        ("[camera]\ngain = 1\n", "unknown key camera.gain (did you mean gain_db?)"),
        ("[camera]\nexposure_us = 1.5\n", "[camera] exposure_us must be a whole number of micro"),
        ("camera = 3\n", "[camera] must be a table"),
    ],
)
def test_an_unknown_section_key_or_value_is_one_line_with_the_nearest_name(
    tmp_path: Path, text: str, message: str
) -> None:
    with pytest.raises(UserError) as caught:
        check(tmp_path, text, registry(("cam", CameraPlugin())))
    assert str(caught.value).startswith(f"{tmp_path / 'site.toml'}: ")
    assert message in str(caught.value)
    assert "\n" not in str(caught.value)


def test_declared_and_core_sections_are_accepted(tmp_path: Path) -> None:
    text = (
        "[camera]\nexposure_us = 200\n[cameras.left]\nanything = 1\n"
        '[scheduler]\ntimezone = "UTC"\n[processors.linescan-stereo]\n[maintenance]\n'
    )
    check(tmp_path, text, registry(("cam", CameraPlugin())))


def test_a_plugin_declaring_a_core_section_is_a_load_error() -> None:
    found = registry(("greedy", GreedyPlugin()))
    assert list(found.config_sections()) == ["webcam"]
    messages = [str(error) for error in found.errors]
    assert messages == [
        "plugin 'greedy' (load): config section [database] is the core's",
        "plugin 'greedy' (load): config section [scheduler] is the core's",
    ]


def test_a_disabled_plugins_section_is_unknown(tmp_path: Path) -> None:
    with pytest.raises(UserError, match=r"unknown section \[camera\]"):
        check(tmp_path, "[camera]\n", registry())


def test_the_invocations_settings_are_checked_and_its_registry_is_not(tmp_path: Path) -> None:
    """A command that uses the settings refuses the section; ``catenary plugins`` (the
    registry alone) still lists the plugins, to find the one that should declare it."""
    config = tmp_path / "site.toml"
    config.write_text('[databse]\nurl = "sqlite:///elsewhere.sqlite"\n')
    context = CommandContext(config_path=config)
    assert "wiretypes" in context.registry.plugin_names
    with pytest.raises(UserError, match=r"unknown section \[databse\]"):
        context.settings  # noqa: B018
    listed = CliRunner().invoke(cli, ["--config", str(config), "plugins"])
    assert listed.exit_code == 0, listed.output
    refused = CliRunner().invoke(cli, ["--config", str(config), "alerts", "list"])
    assert refused.exit_code == 1
    assert refused.output == (
        f"Error: {config}: unknown section [databse] (did you mean [database]?)\n"
    )
    assert not (tmp_path / "elsewhere.sqlite").exists()
