"""Benchmark: stream a recorded run file back through ``RunFile.blocks()``.

Writes (to a temporary directory) a run of four 4096-pixel uint8 cameras whose lines look like
the real thing — a smooth sky background with vignetting and slow drift, sensor noise, and
three bright contact-wire peaks zig-zagging across the line — so that it compresses like real
data (neither all zeros nor pure noise), then times reading it back in blocks, in a fresh
process so that its peak RSS is the reader's own. The target is >= 100,000 scans/s.

    .venv/bin/python benchmarks/read_runfile.py                  # the default compression
    .venv/bin/python benchmarks/read_runfile.py --compare        # none, lzf, gzip 1/4/6
    .venv/bin/python benchmarks/read_runfile.py --compression gzip --level 1 --scans 32768

The file is read right after it is written, so from the page cache: the figures are the
reader's CPU cost (decompression, copies), not the disk's.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from catenary.measurement.runfile import DEFAULT_COMPRESSION, RunFileWriter, open_run

CAMERAS = ("left", "centre_left", "centre_right", "right")
PIXELS = 4096
TARGET_SCANS_PER_S = 100_000


def synthetic_lines(
    first_scan: int, n: int, camera: int, rng: np.random.Generator, noise_dn: float
) -> np.ndarray:
    """``[n, PIXELS]`` uint8 lines of one camera: sky, noise and three wire peaks."""
    u = np.arange(PIXELS, dtype=np.float32)
    s = np.arange(first_scan, first_scan + n, dtype=np.float32)[:, None]
    vignetting = 40.0 * np.cos((u - PIXELS / 2) / PIXELS * np.pi) ** 2
    drift = 10.0 * np.sin(s / 3000.0 + camera)
    img = 110.0 + vignetting[None, :] + drift
    img = img + rng.standard_normal((n, PIXELS), dtype=np.float32) * np.float32(noise_dn)
    for wire, base in enumerate((0.3, 0.55, 0.7)):
        centre = PIXELS * base + 300.0 * np.sin(2 * np.pi * s / 20000.0 + wire + camera)
        img += 90.0 * np.exp(-0.5 * ((u[None, :] - centre) / 6.0) ** 2)
    return np.clip(img, 0, 255).astype(np.uint8)


def write_run(
    path: Path, scans: int, compression: str | None, level: int | None, noise_dn: float
) -> float:
    """Write the run; returns the seconds spent in the writer (not in making the lines)."""
    rng = np.random.default_rng(1)
    block = 1024
    spent = 0.0
    with RunFileWriter(
        path,
        line="BENCH",
        track="1",
        vehicle="bench",
        scan_rate_hz=20_000.0,
        cameras={name: (PIXELS, 8) for name in CAMERAS},
        compression=compression,
        compression_opts=level,
        overwrite=True,
    ) as writer:
        for first in range(0, scans, block):
            n = min(block, scans - first)
            lines = {
                name: synthetic_lines(first, n, c, rng, noise_dn) for c, name in enumerate(CAMERAS)
            }
            index = np.arange(first, first + n)
            t0 = time.perf_counter()
            writer.append(index * 0.005, index / 20_000.0, lines)
            # vehicle sensors at 1 kHz: one sample per 20 scans
            vt = np.arange((first + 19) // 20, (first + n + 19) // 20) / 1000.0
            writer.append_vehicle(vt, np.sin(vt), np.cos(vt), 5 * np.sin(vt / 3))
            spent += time.perf_counter() - t0
        t0 = time.perf_counter()
    return spent + time.perf_counter() - t0


def read_run(path: Path, block_scans: int, repeat: int) -> dict[str, float]:
    """Stream the run ``repeat`` times; the best wall and CPU times, and the peak RSS [MiB].

    CPU time is this process's own (user + system), so it is the one-core cost even when
    other processes share the machine.
    """
    best_wall = best_cpu = float("inf")
    scans = line_bytes = 0
    for _ in range(repeat):
        wall0, cpu0 = time.perf_counter(), time.process_time()
        scans = line_bytes = 0
        with open_run(path) as run:
            for block in run.blocks(block_scans):
                scans += block.scans
                line_bytes += sum(c.lines.nbytes for c in block.cameras.values())
        best_wall = min(best_wall, time.perf_counter() - wall0)
        best_cpu = min(best_cpu, time.process_time() - cpu0)
    peak_kib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {
        "scans": scans,
        "seconds": best_wall,
        "cpu_seconds": best_cpu,
        "line_bytes": line_bytes,
        "peak_rss_mib": peak_kib / 1024,
    }


def bench(
    tmp: Path,
    scans: int,
    block_scans: int,
    repeat: int,
    compression: str | None,
    level: int | None,
    noise_dn: float,
) -> dict[str, float]:
    label = compression or "none"
    if compression == "gzip" and level is not None:
        label += f" {level}"
    path = tmp / f"run-{label.replace(' ', '')}.h5"
    write_s = write_run(path, scans, compression, level, noise_dn)
    size = path.stat().st_size
    out = subprocess.run(
        [
            sys.executable,
            __file__,
            *("--read-only", str(path)),
            *("--block-scans", str(block_scans)),
            *("--repeat", str(repeat)),
        ],
        check=True,
        capture_output=True,
        text=True,
    )
    result: dict[str, float] = json.loads(out.stdout)
    rate = result["scans"] / result["seconds"]
    cpu_rate = result["scans"] / result["cpu_seconds"]
    raw = scans * PIXELS * len(CAMERAS)
    print(
        f"{label:7s} ratio {raw / size:4.2f} | write {scans / write_s:8,.0f} scans/s | "
        f"read {rate:8,.0f} scans/s ({cpu_rate:8,.0f} per CPU-s), "
        f"{result['line_bytes'] / result['seconds'] / 1e6:6,.0f} MB/s of lines, "
        f"{size / result['seconds'] / 1e6:6,.0f} MB/s of file | "
        f"peak RSS {result['peak_rss_mib']:5.0f} MiB | "
        f"{'meets' if rate >= TARGET_SCANS_PER_S else 'BELOW'} target",
        flush=True,
    )
    path.unlink()
    return result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scans", type=int, default=65536)
    parser.add_argument("--block-scans", type=int, default=1024)
    parser.add_argument("--repeat", type=int, default=3, help="read passes; the best counts")
    parser.add_argument(
        "--compression", choices=("default", "none", "gzip", "lzf"), default="default"
    )
    parser.add_argument("--level", type=int, default=None, help="gzip level")
    parser.add_argument("--noise-dn", type=float, default=2.0, help="sensor noise, grey levels RMS")
    parser.add_argument("--compare", action="store_true", help="none, lzf and gzip levels 1, 4, 6")
    parser.add_argument(
        "--dir", type=Path, default=None, help="where to write (default: a temp dir)"
    )
    parser.add_argument("--read-only", type=Path, default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()

    if args.read_only is not None:
        print(json.dumps(read_run(args.read_only, args.block_scans, args.repeat)))
        return

    if args.compare:
        settings: list[tuple[str | None, int | None]] = [
            (None, None),
            ("lzf", None),
            ("gzip", 1),
            ("gzip", 4),
            ("gzip", 6),
        ]
    elif args.compression == "default":
        settings = [(DEFAULT_COMPRESSION, None)]
    else:
        settings = [(None if args.compression == "none" else args.compression, args.level)]
    print(
        f"{args.scans:,} scans of {len(CAMERAS)} x {PIXELS}-pixel uint8 cameras "
        f"({args.scans * PIXELS * len(CAMERAS) / 1e9:.2f} GB of lines), noise {args.noise_dn} DN, "
        f"blocks of {args.block_scans} scans, default compression {DEFAULT_COMPRESSION!r}; "
        f"target {TARGET_SCANS_PER_S:,} scans/s",
        flush=True,
    )
    with tempfile.TemporaryDirectory(dir=args.dir) as tmp:
        for compression, level in settings:
            bench(
                Path(tmp),
                args.scans,
                args.block_scans,
                args.repeat,
                compression,
                level,
                args.noise_dn,
            )
    print(f"(python {sys.version.split()[0]}, {os.cpu_count()} CPUs)")


if __name__ == "__main__":
    main()
