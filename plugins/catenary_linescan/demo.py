"""``catenary demo``: the main job on simulated data, for a newcomer.

Simulates a few hundred metres of line with an overlap on the demo rig (run file, ground
truth, mast register, calibration captures), calibrates the rig from the captures, and
registers the vehicle and its rig calibration in the database (the embedded SQLite default
unless ``--db`` says otherwise), migrating it first. Processing the run into per-span wear
joins the demo with ``catenary process``.
"""

from __future__ import annotations

import time
from pathlib import Path

import click

from catenary.cli import app_of
from catenary.storage import migrate
from catenary.storage.database import mask_url, open_database, session_scope
from catenary.storage.rigs import register_rig_calibration
from catenary_linescan.calibrate import calibrate
from catenary_linescan.rig import read_rig
from catenary_linescan.simulator.command import simulate
from catenary_linescan.simulator.settings import DEMO_RIG_PATH


@click.command("demo")
@click.option(
    "--out",
    type=click.Path(path_type=Path, file_okay=False),
    default=Path("catenary-demo"),
    show_default=True,
    help="Folder for the demo's files (created; files in it are replaced).",
)
@click.option("--length-m", type=float, default=300.0, show_default=True, help="Run length.")
@click.option("--seed", type=int, default=7, show_default=True, help="Scene, motion and noise.")
@click.pass_context
def demo(ctx: click.Context, out: Path, length_m: float, seed: int) -> None:
    """Simulate a run on the demo rig, calibrate the rig, and store it in the database."""
    started = time.monotonic()
    settings = app_of(ctx).settings
    out.mkdir(parents=True, exist_ok=True)
    run, captures, rig_path = out / "run.h5", out / "captures.h5", out / "rig.toml"

    click.echo(f"1/3 simulating {length_m:g} m of line with an overlap on the demo rig")
    ctx.invoke(
        simulate,
        out=run,
        rig_path=DEMO_RIG_PATH,
        length_m=length_m,
        seed=seed,
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

    click.echo("2/3 calibrating the rig from its captures")
    ctx.invoke(
        calibrate,
        captures=captures,
        vehicle_path=DEMO_RIG_PATH,
        output=rig_path,
        distortion="auto",
        approximate_path=None,
        pixels=None,
    )

    click.echo("3/3 storing the vehicle and its rig calibration")
    rig = read_rig(rig_path)
    with open_database(settings.database_url, migrated=False) as engine:
        migrate.upgrade(engine)
        with session_scope(engine) as session:
            stored = register_rig_calibration(
                session, rig.vehicle, rig_path.stem, rig_path.read_text(encoding="utf-8")
            )
            version = stored.version
    where = mask_url(settings.database_url)
    click.echo("")
    click.echo(f"run file          {run} (truth: {run.with_suffix('.truth.h5').name})")
    click.echo(f"mast register     {run.with_suffix('.masts.csv')}")
    click.echo(f"captures          {captures}")
    click.echo(f"rig calibration   {rig_path} (version {version} of {rig.vehicle.name!r})")
    click.echo(f"database          {where}")
    click.echo(f"done in {time.monotonic() - started:.0f} s")
