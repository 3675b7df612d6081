"""``catenary demo``: the main job on simulated data, for a newcomer.

Simulates a few hundred metres of line with an overlap on the demo rig (run file, ground
truth, mast register, calibration captures), calibrates the rig from the captures, migrates
the database (the embedded SQLite default unless ``--db`` says otherwise), processes the run
into it as ``catenary process`` does (aligned to the mast register; the demo run again is a
new recording, so a new run), evaluates the wear limits on it (the config's ``[limits]``
policy, else the preset ``DEMO_POLICY``), and writes the run report (HTML, the ``run``
reporter) and the run's spans (CSV) beside the files.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from catenary.limits import thresholds
from catenary.plugins import CommandContext
from catenary_linescan.calibrate import calibrate_rig
from catenary_linescan.simulator.command import simulate_run
from catenary_linescan.simulator.settings import DEMO_RIG_PATH

DEMO_POLICY = "manufacturer-30pct"
"""The wear limits without a configured policy (the simulated wire is fairly new: no alert)."""


def run_demo(context: CommandContext, out: Path, length_m: float, seed: int) -> None:
    """What ``catenary demo`` does (module docstring)."""
    from catenary.limits import choose_policy
    from catenary.maintenance.alerts import evaluate_stored_run, run_alerting, run_alerts_lines
    from catenary.maintenance.reports import report_request
    from catenary.measurement.export import export_run
    from catenary.measurement.process import ProcessRequest, process_run
    from catenary.storage import migrate
    from catenary.storage.database import mask_url

    started = time.monotonic()
    settings, registry = context.settings, context.registry
    presets = registry.limit_policies()
    configured = choose_policy(settings, presets)
    policy = configured or presets[DEMO_POLICY]
    out.mkdir(parents=True, exist_ok=True)
    run, captures, rig_path = out / "run.h5", out / "captures.h5", out / "rig.toml"

    click.echo(f"1/4 simulating {length_m:g} m of line with an overlap on the demo rig")
    simulate_run(
        out=run,
        rig_path=DEMO_RIG_PATH,
        length_m=length_m,
        seed=seed,
        scene_seed=None,
        lighting="night",
        overlap=True,
        sun_blind=None,
        captures_path=captures,
        speed_kmh=60.0,
        scan_rate_hz=1000.0,
        direction="increasing",
        wire_type="CTA120",
        curve_radius_m=None,
        overwrite=True,
    )

    click.echo("2/4 calibrating the rig from its captures")
    calibrate_rig(
        captures=captures,
        vehicle_path=DEMO_RIG_PATH,
        output=rig_path,
        distortion="auto",
        approximate_path=None,
        pixels=None,
    )

    click.echo("3/4 processing the run into the database")
    with context.database(migrated=False, create=True) as engine:
        migrate.upgrade(engine)
    masts = run.with_suffix(".masts.csv")
    alerting = run_alerting(settings, registry, policy)
    process_request = ProcessRequest(run_path=run, rig_path=rig_path, register_path=masts)
    result = process_run(process_request, settings, registry)
    with context.database() as engine:
        alerts = evaluate_stored_run(alerting, engine, settings, registry, result.run_id)
    for text in [*result.summary_lines(), *run_alerts_lines(alerts)]:
        click.echo(text)
    click.echo(f"stored as run {result.run_id}")

    click.echo("4/4 writing the reports")
    spans = out / "spans.csv"
    written = export_run(settings, str(result.run_id), "spans", spans).rows
    click.echo(f"{written} spans of run {result.run_id} written to {spans}")
    preset = None if configured else DEMO_POLICY  # None: the config's own
    request = report_request(settings, registry, runs=(str(result.run_id),), policy=preset)
    report = registry.reporters()["run"].write(request, out / "report.html")
    click.echo("")
    click.echo(f"run file          {run} (truth: {run.with_suffix('.truth.h5').name})")
    click.echo(f"mast register     {masts}")
    click.echo(f"captures          {captures}")
    click.echo(f"rig calibration   {rig_path}")
    click.echo(f"database          {mask_url(settings.database_url)} (run {result.run_id})")
    click.echo(f"samples           {result.samples_where}")
    click.echo(f"report            {report} (the run report: open it in a browser)")
    click.echo(f"spans             {spans} (one row per span and wire)")
    raised = len(alerts.new) if alerts else 0
    why = " (catenary alerts list)"
    minimum = result.minimum
    if raised == 0 and minimum is not None:
        wire = registry.wire_types()[minimum.wire_type]
        limits = [t.residual_thickness_mm for t in thresholds(wire, policy) if t.scope == "local"]
        limit = f", the first limit {max(limits):.2f} mm" if limits else ""
        why = f": the thinnest wire has {minimum.min_residual_thickness_mm:.2f} mm left{limit}"
    click.echo(f"alerts            {raised} new, policy {policy.name}{why}")
    click.echo(f"done in {time.monotonic() - started:.0f} s")
