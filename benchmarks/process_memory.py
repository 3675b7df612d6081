"""Benchmark: ``catenary process`` keeps its memory flat whatever the run's length.

Simulates two runs of the same kind, one ten times longer than the other (an overlap in
each, mast register beside them), calibrates the demo rig from simulated captures, and
processes each run with the real command in a child process into a fresh SQLite database,
reporting the child's peak resident memory (``ru_maxrss``), its wall time and its scans per
second, and what it stored.

Memory reaches its plateau once the first Parquet row group (16,384 samples, about 15 blocks
of 1024 scans) has been written; compare runs longer than that.

    .venv/bin/python benchmarks/process_memory.py                    # 1,000 m and 10,000 m
    .venv/bin/python benchmarks/process_memory.py --length-m 300     # 300 m and 3,000 m
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures

CATENARY = Path(sys.executable).with_name("catenary")


def run_command(args: list[str], env: dict[str, str]) -> tuple[float, float, str]:
    """Run ``catenary ARGS`` in a child; returns (peak RSS MiB, seconds, its output)."""
    started = time.perf_counter()
    child = subprocess.Popen(
        [str(CATENARY), *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT, env=env
    )
    assert child.stdout is not None
    output = child.stdout.read().decode()
    _, status, usage = os.wait4(child.pid, 0)
    seconds = time.perf_counter() - started
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"catenary {' '.join(args)} failed:\n{output}")
    return usage.ru_maxrss / 1024.0, seconds, output


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--length-m", type=float, default=1000.0, help="the shorter run")
    parser.add_argument("--speed-kmh", type=float, default=160.0)
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = {**os.environ, "CATENARY_DATA_DIR": str(folder / "data")}
        captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
        rig = folder / "rig.toml"
        run_command(
            ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(rig)], env
        )
        database = f"sqlite:///{folder / 'bench.sqlite'}"
        run_command(["--db", database, "db", "upgrade"], env)
        print(f"{'length m':>9} {'scans':>7} {'peak RSS MiB':>13} {'seconds':>8} {'scans/s':>8}")
        for factor in (1, 10):
            length = args.length_m * factor
            run = folder / f"run-{factor}.h5"
            recorded = record_run(
                run,
                {"length_m": length, "overlap": True, "speed_kmh": args.speed_kmh, "seed": 11},
            )
            masts = run.with_suffix(".masts.csv")
            command = ["process", str(run), "--rig", str(rig), "--masts", str(masts)]
            rss, seconds, output = run_command([*command, "--db", database], env)
            scans, rate = recorded.scans, recorded.scans / seconds
            print(f"{length:>9.0f} {scans:>7d} {rss:>13.1f} {seconds:>8.1f} {rate:>8.0f}")
            for line in output.splitlines():
                if line.startswith(("spans", "minimum", "chainage")):
                    print(f"          {line}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
