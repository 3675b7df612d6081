"""``catenary wire-types``: the wire types, and one type's wear table and a policy's limits."""

from __future__ import annotations

from pathlib import Path

import click
import numpy as np

from catenary.cli.app import app_of
from catenary.errors import UserError
from catenary.limits import LimitPolicy, choose_policy, thresholds
from catenary.wiretype import WireType

__all__ = ["wire_types_command"]


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
    click.echo(f"  standard limit: {wire.standard_limit}")
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


@click.command("wire-types")
@click.argument("name", required=False)
@click.option(
    "--policy",
    "policy_name",
    metavar="NAME",
    help="Show the thresholds of this wear-limit policy (default: the config's [limits], "
    "else the wire types' standard limits).",
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
        policy = choose_policy(
            app.settings,
            registry.limit_policies(),
            policy_name,
            policy_file,
            wire_types=wire_types,
        )
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
