"""Benchmark: ``catenary reprocess`` of a batch of runs on a Dask local cluster of 1 and of 2
worker processes: wall time, scans per second, speed-up and peak memory per worker.

Simulates ``--runs`` runs of ``--length-m`` at 160 km/h on the demo rig (one line, measured
again: one scene, a seed each), calibrates the rig from simulated captures, and processes
each run once with ``catenary process`` into a new SQLite database (or a new schema of the
PostgreSQL database ``--database-url``, dropped at the end). Then it times the real command
``catenary reprocess --rig RIG --workers N`` in a child process for each ``--workers`` count,
alternated ``--repeats`` times; each time the rig calibration has new content (a comment
added), so every run is processed again and stored as a new processing (checked: all
stored, none skipped).

Per command: its wall time (all of it: the cluster's start-up, the workers' imports, the
tasks), the batch's scans over it, the sum of the runs' task times (as the command prints
them), the speed-up over the first count's median wall time, and the peak resident memory
(``VmHWM``) of each worker process and of the command's own process (client, scheduler and
nannies), found with psutil among this script's descendants and read from /proc until they
exit (Linux).

    .venv/bin/python benchmarks/reprocess_batch.py                   # 4 runs of 600 m, 3 times
    .venv/bin/python benchmarks/reprocess_batch.py --runs 8 --repeats 1
    .venv/bin/python benchmarks/reprocess_batch.py \\
        --database-url postgresql+psycopg://postgres@127.0.0.1:5432/test
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import psutil
from fleet_push import postgres_schema
from process_memory import CATENARY, run_command
from sqlalchemy.engine import make_url

from catenary_linescan.simulator import DEMO_RIG_PATH, load_rig, record_run
from catenary_linescan.simulator.captures import write_captures

SPEED_KMH = 160.0
SCENE_SEED = 1
SAMPLE_S = 0.1


@dataclass
class Peaks:
    """Peak resident memory (MiB) of the command's own process and of each worker process."""

    command_mib: float
    workers_mib: list[float]


def _hwm_mib(pid: int) -> float:
    """The process's peak resident memory so far (``VmHWM``), MiB; 0 once it has gone."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0.0
    found = re.search(r"^VmHWM:\s+(\d+) kB", status, re.MULTILINE)
    return 0.0 if found is None else int(found.group(1)) / 1024.0


@contextmanager
def sampled_peaks() -> Iterator[Peaks]:
    """Reads, every ``SAMPLE_S`` while the block runs, the peak memory of the ``catenary``
    processes among this script's descendants and of their Dask worker processes (spawned:
    ``spawn_main`` in their command line); the figures are in the ``Peaks`` yielded once the
    block ends."""
    peaks: dict[int, tuple[str, float]] = {}
    stop = threading.Event()

    def sample() -> None:
        while not stop.wait(SAMPLE_S):
            for child in psutil.Process().children(recursive=True):
                try:
                    command_line = child.cmdline()
                except psutil.Error:
                    continue
                if "spawn_main" in " ".join(command_line):
                    kind = "worker"
                elif str(CATENARY) in command_line[:2]:
                    kind = "command"
                else:
                    continue
                previous = peaks.get(child.pid, (kind, 0.0))[1]
                peaks[child.pid] = kind, max(previous, _hwm_mib(child.pid))

    result = Peaks(0.0, [])
    sampler = threading.Thread(target=sample, daemon=True)
    sampler.start()
    try:
        yield result
    finally:
        stop.set()
        sampler.join()
    result.command_mib = max((mib for kind, mib in peaks.values() if kind == "command"), default=0)
    result.workers_mib = [mib for kind, mib in peaks.values() if kind == "worker"]


def simulate(folder: Path, runs: int, length_m: float) -> tuple[list[Path], int]:
    """The batch's run files (one line, a seed each) and their scans in all."""
    paths, scans = [], 0
    for seed in range(1, runs + 1):
        path = folder / f"run-{seed}.h5"
        settings = {"length_m": length_m, "speed_kmh": SPEED_KMH, "seed": seed}
        scans += record_run(path, {**settings, "scene_seed": SCENE_SEED}).scans
        paths.append(path)
    return paths, scans


@contextmanager
def database(url: str | None, folder: Path, env: dict[str, str]) -> Iterator[str]:
    """A new, migrated database: a schema of the PostgreSQL database ``url``, dropped at the
    end, or without ``url`` an SQLite file in ``folder``; its URL."""
    if url is not None:
        with postgres_schema(url) as schema_url:
            yield schema_url
        return
    sqlite = f"sqlite:///{folder / 'bench.sqlite'}"
    run_command(["--db", sqlite, "db", "upgrade"], env)
    yield sqlite


def reprocess(
    database: str, rig: Path, workers: int, label: str, env: dict[str, str]
) -> tuple[float, float, Peaks]:
    """``catenary reprocess`` of every run with ``rig`` changed (``label``), so all are
    processed again: its wall time, the sum of its task times (s) and its peak memory."""
    new_rig = rig.with_name(f"rig-{label}.toml")
    new_rig.write_text(rig.read_text() + f"\n# reprocess_batch {label}\n")
    with sampled_peaks() as peaks:
        _, seconds, output = run_command(
            ["--db", database, "reprocess", "--rig", str(new_rig), "--workers", str(workers)], env
        )
    summary = re.search(r"^reprocessed (\d+) run\(s\).*: (\d+) stored", output, re.MULTILINE)
    if summary is None or summary.group(1) != summary.group(2):
        raise SystemExit(f"catenary reprocess did not store every run:\n{output}")
    task_s = sum(float(s) for s in re.findall(r"^run .*: stored .* in ([0-9.]+) s", output, re.M))
    return seconds, task_s, peaks


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=4)
    parser.add_argument("--length-m", type=float, default=600.0)
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--database-url", help="PostgreSQL (a new schema); default: SQLite")
    args = parser.parse_args(argv)
    if args.database_url and make_url(args.database_url).get_backend_name() != "postgresql":
        raise SystemExit(f"--database-url {args.database_url}: give a PostgreSQL URL")
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        env = {**os.environ, "CATENARY_DATA_DIR": str(folder / "data")}
        runs, scans = simulate(folder, args.runs, args.length_m)
        captures, _ = write_captures(folder / "captures.h5", load_rig(DEMO_RIG_PATH), seed=2)
        rig = folder / "rig.toml"
        run_command(
            ["calibrate", str(captures), "--vehicle", str(DEMO_RIG_PATH), "-o", str(rig)], env
        )
        with database(args.database_url, folder, env) as url:
            for run in runs:
                masts = run.with_suffix(".masts.csv")
                run_command(
                    ["--db", url, "process", str(run), "--rig", str(rig), "--masts", str(masts)],
                    env,
                )
            backend = make_url(url).get_backend_name()
            print(
                f"{args.runs} runs of {args.length_m:.0f} m ({scans} scans) on {backend}; "
                f"load average before {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}"
            )
            print(f"{'workers':>7} {'wall s':>7} {'task s':>7} {'command MiB':>11}  worker MiB")
            walls: dict[int, list[float]] = {n: [] for n in args.workers}
            for repeat in range(args.repeats):
                order = args.workers if repeat % 2 == 0 else args.workers[::-1]
                for workers in order:
                    seconds, task_s, peaks = reprocess(
                        url, rig, workers, f"{repeat}-{workers}", env
                    )
                    walls[workers].append(seconds)
                    worker_mib = " ".join(f"{mib:.0f}" for mib in sorted(peaks.workers_mib))
                    print(
                        f"{workers:>7} {seconds:>7.1f} {task_s:>7.1f} "
                        f"{peaks.command_mib:>11.0f}  {worker_mib}"
                    )
    base = statistics.median(walls[args.workers[0]])
    print(f"{'workers':>7} {'median s':>8} {'scans/s':>8} {'speed-up':>8}")
    for workers, seconds in walls.items():
        median = statistics.median(seconds)
        print(f"{workers:>7} {median:>8.1f} {scans / median:>8.0f} {base / median:>8.2f}")
    load = os.getloadavg()
    print(f"load average after {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
