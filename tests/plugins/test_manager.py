"""The plugin registry: every way a plugin can fail is reported by name, the rest keep working."""

from __future__ import annotations

import types
from pathlib import Path
from typing import Any

import pytest
from click.testing import CliRunner

from catenary.cli import cli
from catenary.plugins import PluginError, PluginRegistry, hookimpl
from catenary.wiretype import WireType


def _wire(name: str, standard: str = "test") -> WireType:
    return WireType(
        name=name,
        standard=standard,
        height_mm=12.0,
        width_mm=12.0,
        area_mm2=100.0,
        nominal_area_mm2=100.0,
    )


class WirePlugin:
    """A plugin object returning whatever it is given from ``catenary_wire_types``."""

    def __init__(self, *items: Any) -> None:
        self.items = list(items)

    @hookimpl
    def catenary_wire_types(self) -> list[Any]:
        return self.items


class RaisingPlugin:
    @hookimpl
    def catenary_wire_types(self) -> list[WireType]:
        raise RuntimeError("profile table\nis broken")

    @hookimpl
    def catenary_run_stored(self, run_id: int, database_url: str) -> None:
        raise OSError("disk full")


class MisspeltPlugin:
    @hookimpl
    def catenary_wire_type(self) -> list[WireType]:  # singular: no such hook
        return [_wire("NEVER")]


class Listener:
    def __init__(self) -> None:
        self.seen: list[int] = []

    @hookimpl
    def catenary_run_stored(self, run_id: int, database_url: str) -> None:
        self.seen.append(run_id)


def test_two_plugins_registering_the_same_wire_type() -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[
            ("first", WirePlugin(_wire("T-1", standard="first's"))),
            ("second", WirePlugin(_wire("T-1", standard="second's"), _wire("T-2"))),
        ],
    )
    wires = registry.wire_types()
    assert wires["T-1"].standard == "first's"
    assert registry.owner("wire type", "T-1") == "first"
    assert registry.owner("wire type", "T-2") == "second"
    assert registry.errors == [
        PluginError(
            "second",
            "catenary_wire_types",
            "wire type 'T-1' is already registered by plugin 'first'",
        )
    ]
    assert "plugin 'second' (catenary_wire_types)" in str(registry.errors[0])


def test_a_plugin_raising_inside_a_hook_is_reported_and_others_work() -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[("good", WirePlugin(_wire("T-1"))), ("broken", RaisingPlugin())],
    )
    assert list(registry.wire_types()) == ["T-1"]
    assert registry.errors == [
        PluginError("broken", "catenary_wire_types", "RuntimeError: profile table is broken")
    ]
    registry.wire_types()  # collected once: the error is not reported again
    assert len(registry.errors) == 1


def test_an_event_hook_raising_is_reported_and_others_are_still_called() -> None:
    listener = Listener()
    registry = PluginRegistry(
        autoload=False, plugins=[("broken", RaisingPlugin()), ("listener", listener)]
    )
    registry.run_stored(7, "sqlite://")
    assert listener.seen == [7]
    assert registry.errors == [PluginError("broken", "catenary_run_stored", "OSError: disk full")]


@pytest.mark.parametrize(
    ("returned", "message"),
    [
        (["CTA120"], "returned str, not a WireType"),
        ([{"name": "T-9"}], "returned dict, not a WireType"),
    ],
)
def test_a_plugin_returning_the_wrong_type(returned: list[Any], message: str) -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[("odd", WirePlugin(*returned, _wire("T-2"))), ("good", WirePlugin(_wire("T-1")))],
    )
    assert sorted(registry.wire_types()) == ["T-1", "T-2"]
    assert registry.errors == [PluginError("odd", "catenary_wire_types", message)]


def test_a_plugin_returning_one_object_instead_of_a_list() -> None:
    single = types.SimpleNamespace(catenary_wire_types=hookimpl(lambda: _wire("T-1")))
    registry = PluginRegistry(autoload=False, plugins=[("single", single)])
    assert registry.wire_types() == {}
    (error,) = registry.errors
    assert (error.plugin, error.stage) == ("single", "catenary_wire_types")
    assert "not iterable" in error.message


def test_a_misspelt_hook_implementation_is_a_load_error() -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[("typo", MisspeltPlugin()), ("good", WirePlugin(_wire("T-1")))],
    )
    assert registry.plugin_names == ["good"]
    (error,) = registry.errors
    assert (error.plugin, error.stage) == ("typo", "load")
    assert "catenary_wire_type" in error.message
    assert list(registry.wire_types()) == ["T-1"]


def test_two_plugins_of_one_name() -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[("same", WirePlugin(_wire("T-1"))), ("same", WirePlugin(_wire("T-2")))],
    )
    assert list(registry.wire_types()) == ["T-1"]
    assert registry.errors == [PluginError("same", "load", "a plugin of this name is loaded")]


def test_disabled_plugins_are_not_loaded() -> None:
    registry = PluginRegistry(
        autoload=False,
        plugins=[("a", WirePlugin(_wire("T-1"))), ("b", WirePlugin(_wire("T-2")))],
        disabled=["b"],
    )
    assert registry.plugin_names == ["a"]
    assert list(registry.wire_types()) == ["T-1"]
    assert registry.errors == []


@pytest.fixture
def broken_distribution(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """A fake installed distribution on sys.path with two entry points that fail to import."""
    site = tmp_path / "site"
    dist_info = site / "catenary_broken_plugins-1.0.dist-info"
    dist_info.mkdir(parents=True)
    (dist_info / "METADATA").write_text(
        "Metadata-Version: 2.1\nName: catenary-broken-plugins\nVersion: 1.0\n"
    )
    (dist_info / "entry_points.txt").write_text(
        "[catenary.plugins]\n"
        "missing = catenary_no_such_module_xyz\n"
        "crashing = catenary_crashing_plugin_xyz\n"
    )
    (site / "catenary_crashing_plugin_xyz.py").write_text(
        'raise ImportError("needs libfoo, which is not installed")\n'
    )
    monkeypatch.syspath_prepend(str(site))
    return site


def test_an_entry_point_that_fails_to_import(broken_distribution: Path) -> None:
    registry = PluginRegistry()
    failed = {error.plugin: error for error in registry.errors}
    assert set(failed) == {"missing", "crashing"}
    assert failed["missing"].stage == "load"
    assert "ModuleNotFoundError" in failed["missing"].message
    assert failed["crashing"].message == "ImportError: needs libfoo, which is not installed"
    assert "wiretypes" in registry.plugin_names  # the built-ins still load
    assert "CTA120" in registry.wire_types()


def test_builtins_only_skips_third_party_entry_points(
    broken_distribution: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("CATENARY_DISABLE_PLUGIN_AUTOLOAD", "1")
    registry = PluginRegistry()
    assert registry.errors == []
    assert "wiretypes" in registry.plugin_names


def test_plugins_command_lists_load_errors(broken_distribution: Path) -> None:
    result = CliRunner().invoke(cli, ["plugins"])
    assert result.exit_code == 0, result.output
    assert "wiretypes" in result.stdout
    assert "errors:" in result.stderr
    assert "plugin 'crashing' (load): ImportError: needs libfoo" in result.stderr
    assert "plugin 'missing' (load): ModuleNotFoundError" in result.stderr
    assert "Traceback" not in result.output
    strict = CliRunner().invoke(cli, ["plugins", "--strict"])
    assert strict.exit_code == 1


def test_every_hook_is_documented_and_has_a_registry_caller() -> None:
    """As datasette does: a hook without documentation, or that nothing calls, fails."""
    import inspect

    from catenary.plugins import hookspecs
    from catenary.plugins import manager as plugins

    hooks = [
        name
        for name, function in inspect.getmembers(hookspecs, inspect.isfunction)
        if name.startswith("catenary_")
    ]
    assert len(hooks) >= 10
    registry_source = inspect.getsource(plugins)
    for name in hooks:
        doc = inspect.getdoc(getattr(hookspecs, name)) or ""
        assert len(doc.split()) >= 8, f"hook {name} is not documented"
        assert f'"{name}"' in registry_source, f"hook {name} is never called by the registry"
