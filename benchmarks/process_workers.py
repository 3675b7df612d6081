"""Benchmark: the marginal rate of the whole ``catenary process`` with ``--workers 1`` and ``N``.

Simulates a run and one four times longer (the same line, an overlap in each, mast register
beside them), calibrates the demo rig from simulated captures, and times the real command in a
child process, each time into a fresh SQLite database and data folder, alternating the
workers (1, N, 1, N, ...) over both runs, three times. The marginal rate of a repetition is
the longer run's extra scans over its extra seconds (start-up, imports and the fixed costs drop
out); the figures are the medians of three, and the speed-up is their ratio. The stored results
of the two are compared: span measurements and samples files must be identical. The load
average (``os.getloadavg``) before and after is printed: other processes on the machine lower
the speed-up.

    .venv/bin/python benchmarks/process_workers.py                   # 500 m and 2,000 m, N = 2
    .venv/bin/python benchmarks/process_workers.py --length-m 300 --workers 4
"""

from __future__ import annotations

import argparse
import os
import sqlite3
import statistics
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow.parquet as pq

sys.path.insert(0, str(Path(__file__).resolve().parent))

from process_memory import run_command

from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures


def stored(database: Path, data: Path) -> tuple[list[tuple[Any, ...]], dict[str, np.ndarray]]:
    """The span measurements (without ids) and the samples file's columns of the one run."""
    with sqlite3.connect(database) as connection:
        names = [
            row[1]
            for row in connection.execute("PRAGMA table_info(span_measurements)")
            if not row[1].endswith("id")
        ]
        spans = connection.execute(
            f"SELECT {', '.join(names)} FROM span_measurements ORDER BY span, wire"
        ).fetchall()
    (samples,) = (path for path in (data / "samples").rglob("*.parquet"))
    table = pq.read_table(samples)
    return spans, {name: table[name].to_numpy() for name in table.column_names}


def identical(a: dict[str, np.ndarray], b: dict[str, np.ndarray]) -> bool:
    """Whether two samples files hold the same columns, bit for bit (NaN equal to NaN)."""
    return a.keys() == b.keys() and all(
        np.array_equal(a[k], b[k], equal_nan=a[k].dtype.kind == "f") for k in a
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--length-m", type=float, default=500.0, help="the shorter run")
    parser.add_argument("--workers", type=int, default=2, help="N, compared with 1")
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args(argv)
    print(f"load average before: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = {**os.environ, "OPENBLAS_NUM_THREADS": "1"}
        captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
        rig = folder / "rig.toml"
        run_command(
            ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(rig)], env
        )
        runs = {}
        for factor in (1, 4):
            run = folder / f"run-{factor}.h5"
            settings = {"length_m": args.length_m * factor, "overlap": True, "seed": 11}
            runs[factor] = run, record_run(run, {**settings, "speed_kmh": 160.0}).scans
        seconds: dict[tuple[int, int], list[float]] = {}
        results = {}
        count = 0
        print(f"{'repeat':>6} {'workers':>7} {'scans':>7} {'seconds':>8} {'peak RSS MiB':>13}")
        for repeat in range(args.repeat):
            for factor in (1, 4):
                for workers in (1, args.workers):
                    count += 1
                    database = folder / f"bench-{count}.sqlite"
                    data = folder / f"data-{count}"
                    url = f"sqlite:///{database}"
                    run_command(["--db", url, "db", "upgrade"], env)
                    run, scans = runs[factor]
                    command = ["process", str(run), "--rig", str(rig), "--masts"]
                    command += [str(run.with_suffix(".masts.csv")), "--workers", str(workers)]
                    rss, took, _ = run_command(
                        [*command, "--db", url], {**env, "CATENARY_DATA_DIR": str(data)}
                    )
                    seconds.setdefault((factor, workers), []).append(took)
                    print(f"{repeat:>6} {workers:>7} {scans:>7} {took:>8.2f} {rss:>13.1f}")
                    if repeat == 0 and factor == 4:
                        results[workers] = stored(database, data)
        extra = runs[4][1] - runs[1][1]
        rates = {
            workers: statistics.median(
                extra / (long - short)
                for short, long in zip(seconds[1, workers], seconds[4, workers], strict=True)
            )
            for workers in (1, args.workers)
        }
        (spans_1, samples_1), (spans_n, samples_n) = results[1], results[args.workers]
        same = spans_1 == spans_n and identical(samples_1, samples_n)
    for workers, rate in rates.items():
        print(f"marginal rate, --workers {workers}: {rate:,.0f} scans/s (median of {args.repeat})")
    print(f"speed-up: {rates[args.workers] / rates[1]:.2f}x")
    print(f"stored results identical (spans and samples): {'yes' if same else 'NO'}")
    print(f"load average after: {' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
