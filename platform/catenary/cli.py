"""The ``catenary`` command line: core subcommands plus those plugins add.

Errors a user can cause (``UserError`` and its kinds, unreadable files, values outside a
profile) are printed as one line without a traceback, with exit status 1; usage errors exit 2.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import click
import numpy as np

from catenary.config import Settings, load_settings
from catenary.errors import UserError
from catenary.limits import (
    LimitPolicy,
    load_policies,
    policy_from_config,
    select_policy,
    thresholds,
)
from catenary.maintenance_commands import alerts, maintenance
from catenary.plugins import PluginRegistry
from catenary.record import record
from catenary.report_command import report
from catenary.run_commands import compare, export, process
from catenary.service_commands import notify, scheduler
from catenary.storage.commands import db
from catenary.wiretype import ProfileRangeError, WireType

F = TypeVar("F", bound=Callable[..., Any])


class App:
    """What one invocation shares: its settings and plugin registry, both made on first use."""

    def __init__(self, config_path: Path | None, database_url: str | None) -> None:
        self._config_path = config_path
        self._database_url = database_url
        self._settings: Settings | None = None
        self._registry: PluginRegistry | None = None

    @property
    def settings(self) -> Settings:
        if self._settings is None:
            self._settings = load_settings(
                config_path=self._config_path, database_url=self._database_url
            )
        return self._settings

    @property
    def registry(self) -> PluginRegistry:
        if self._registry is None:
            self._registry = PluginRegistry(disabled=self.settings.disabled_plugins)
        return self._registry


def app_of(ctx: click.Context) -> App:
    """The invocation's ``App``, kept on the root context."""
    root = ctx.find_root()
    if not isinstance(root.obj, App):
        root.obj = App(root.params.get("config_path"), root.params.get("database_url"))
    return root.obj


def one_line_errors(call: Callable[[], Any]) -> Any:
    """Run ``call``, turning errors a user can cause into a one-line ``ClickException``."""
    try:
        return call()
    except (UserError, ProfileRangeError) as exc:
        raise click.ClickException(str(exc)) from None
    except OSError as exc:
        where = f"{exc.filename}: " if exc.filename else ""
        raise click.ClickException(f"{where}{exc.strerror or exc}") from None


class CatenaryGroup(click.Group):
    """A group whose commands include the plugins' and whose errors are one line."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        names = set(super().list_commands(ctx))
        if self is cli:
            names |= set(one_line_errors(lambda: app_of(ctx).registry.commands()))
        return sorted(names)

    def get_command(self, ctx: click.Context, cmd_name: str) -> click.Command | None:
        command = super().get_command(ctx, cmd_name)
        if command is None and self is cli:
            found = one_line_errors(lambda: app_of(ctx).registry.commands()).get(cmd_name)
            command = None if found is None else found.command
        return command

    def invoke(self, ctx: click.Context) -> Any:
        return one_line_errors(lambda: super(CatenaryGroup, self).invoke(ctx))


@click.group(cls=CatenaryGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.option(
    "--config",
    "config_path",
    type=click.Path(path_type=Path, dir_okay=False),
    help="TOML config file (default: $CATENARY_CONFIG, else config.toml in the user config dir).",
)
@click.option(
    "--db",
    "database_url",
    metavar="URL",
    help="Database URL (default: $CATENARY_DATABASE_URL, else a SQLite file in the data dir).",
)
@click.version_option(package_name="catenary")
@click.pass_context
def cli(ctx: click.Context, config_path: Path | None, database_url: str | None) -> None:
    """Contact wire wear from line-scan stereovision: measure, store, maintain."""
    app_of(ctx)


@cli.command("plugins")
@click.option("--strict", is_flag=True, help="Exit with status 1 if any plugin failed.")
@click.pass_context
def plugins_command(ctx: click.Context, strict: bool) -> None:
    """List the plugins loaded, what each registers, and load errors."""
    registry = app_of(ctx).registry
    for plugin, kinds in registry.registrations().items():
        click.echo(plugin)
        if not kinds:
            click.echo("    (registers nothing)")
        for kind, names in sorted(kinds.items()):
            click.echo(f"    {kind}: {', '.join(names)}")
    if registry.errors:
        click.echo("errors:", err=True)
        for error in registry.errors:
            click.echo(f"    {error}", err=True)
        if strict:
            ctx.exit(1)


def _chosen_policy(app: App, name: str | None, policy_file: Path | None) -> LimitPolicy | None:
    """The policy named on the command line, else the config's ``[limits]``, else None."""
    presets = app.registry.limit_policies()
    if name is None and policy_file is None:
        section = app.settings.sections.get("limits")
        return policy_from_config(section, presets=presets, config_path=app.settings.config_path)
    if policy_file is None:
        assert name is not None
        return select_policy(presets, name, origin="wear-limit presets")
    policies = load_policies(policy_file)
    if name is None:
        if len(policies) != 1:
            known = ", ".join(sorted(policies))
            raise UserError(
                f"{policy_file}: holds several policies, choose one with --policy ({known})"
            )
        (name,) = policies
    return select_policy(policies, name, origin=str(policy_file))


def _wire_type_sort_key(name: str) -> tuple[str, int, str]:
    """``AC-80`` before ``AC-100``: letters, then the size, then the name."""
    letters = name.rstrip("0123456789").rstrip("-")
    digits = name[len(name.rstrip("0123456789")) :]
    return (letters, int(digits) if digits else 0, name)


def _show_wire_type(
    wire: WireType, plugin: str, policy: LimitPolicy | None, presets: list[str]
) -> None:
    legacy = ", legacy (withdrawn from the current edition)" if wire.legacy else ""
    click.echo(f"{wire.name}: {wire.standard}{legacy}; plugin {plugin}")
    click.echo(
        f"  height A {wire.height_mm:.2f} mm, width B {wire.width_mm:.2f} mm, "
        f"cross-section {wire.area_mm2:g} mm2 (nominal {wire.nominal_area_mm2:g} mm2)"
    )
    click.echo(
        f"  residual thickness {wire.height_mm:.2f} mm new down to "
        f"{wire.min_residual_thickness_mm:.2f} mm at full width "
        f"(worn fraction {wire.max_worn_fraction:.3f})"
    )
    if wire.source:
        click.echo(f"  source: {wire.source}")
    click.echo("")
    widths = np.append(np.arange(0.0, np.floor(wire.width_mm) + 1.0), wire.width_mm)
    widths = np.unique(np.minimum(widths, wire.width_mm))
    thickness = wire.residual_thickness_mm(widths)
    area = wire.worn_area_mm2(widths)
    fraction = wire.worn_fraction(widths)
    click.echo(f"  {'width mm':>9} {'thickness mm':>13} {'worn mm2':>9} {'worn %':>7}")
    for row in zip(widths, thickness, area, fraction, strict=True):
        w, h, a, f = (float(x) for x in row)
        click.echo(f"  {w:9.2f} {h:13.3f} {a:9.2f} {100 * f:7.2f}")
    click.echo("")
    if policy is None:
        names = ", ".join(sorted(presets))
        click.echo(
            "  thresholds: choose a wear-limit policy with --policy NAME"
            + (f" (presets: {names})" if names else "")
        )
        return
    click.echo(f"policy {policy.name}: {policy.description}")
    if policy.source:
        click.echo(f"  source: {policy.source}")
    found = thresholds(wire, policy)
    if not found:
        click.echo(f"  no rule of this policy applies to {wire.name}")
        return
    click.echo(
        f"  {'level':<9} {'scope':<23} {'thickness mm':>12} {'worn %':>7} {'width mm':>9}  action"
    )
    for t in found:
        click.echo(
            f"  {t.level:<9} {t.scope:<23} {t.residual_thickness_mm:12.3f} "
            f"{100 * t.worn_fraction:7.2f} {t.wear_width_mm:9.3f}  {t.action}"
        )


@cli.command("wire-types")
@click.argument("name", required=False)
@click.option(
    "--policy",
    "policy_name",
    metavar="NAME",
    help="Show the thresholds of this wear-limit policy (default: the config's [limits]).",
)
@click.option(
    "--policy-file",
    type=click.Path(path_type=Path, dir_okay=False),
    help="A policy TOML file of your own (default: the built-in presets).",
)
@click.pass_context
def wire_types_command(
    ctx: click.Context, name: str | None, policy_name: str | None, policy_file: Path | None
) -> None:
    """List the wire types, or show NAME: geometry, wear table and a policy's thresholds."""
    app = app_of(ctx)
    registry = app.registry
    wire_types = registry.wire_types()
    if name is not None:
        wire = wire_types.get(name)
        if wire is None:
            known = ", ".join(sorted(wire_types, key=_wire_type_sort_key)) or "none"
            raise UserError(f"unknown wire type {name!r} (known: {known})")
        policy = _chosen_policy(app, policy_name, policy_file)
        _show_wire_type(
            wire, registry.owner("wire type", name), policy, list(registry.limit_policies())
        )
        return
    if policy_name is not None or policy_file is not None:
        raise click.UsageError("--policy and --policy-file need a wire type NAME")
    click.echo(f"{'name':<10} {'standard':<16} {'A mm':>6} {'B mm':>6} {'area mm2':>9}  plugin")
    for name_, wire in sorted(wire_types.items(), key=lambda kv: _wire_type_sort_key(kv[0])):
        legacy = " (legacy)" if wire.legacy else ""
        click.echo(
            f"{name_:<10} {wire.standard:<16} {wire.height_mm:6.2f} {wire.width_mm:6.2f} "
            f"{wire.area_mm2:9.1f}  {registry.owner('wire type', name_)}{legacy}"
        )


cli.add_command(db)
cli.add_command(record)
cli.add_command(process)
cli.add_command(export)
cli.add_command(compare)
cli.add_command(notify)
cli.add_command(scheduler)
cli.add_command(report)
cli.add_command(alerts)
cli.add_command(maintenance)


def main(argv: list[str] | None = None) -> None:
    """Console-script entry point."""
    cli.main(args=argv, prog_name="catenary")


if __name__ == "__main__":  # pragma: no cover
    main()
