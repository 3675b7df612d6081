"""Benchmark: a large run file put in an S3 store in parts (``push --run-files``), and resumed.

A file of ``--size-mb`` random bytes is put with ``Store.put_parts`` in parts of ``--part-mb``
to ``rclone serve s3`` on 127.0.0.1 (no network: the rate is this machine's, hashing, HTTP and
rclone's own writing): the rate of sending the parts (each with its MD5, the file's SHA-256
beside), of completing and reading the object back whole to check it, and of the whole put;
this process's and rclone's peak resident memory. Then the same file to another key, cut
after half its parts and put again: the parts sent and found on resuming, and its time.

    nice -n 10 .venv/bin/python benchmarks/store_parts.py              # 1,024 MB in 64 MB parts
    nice -n 10 .venv/bin/python benchmarks/store_parts.py --size-mb 256 --part-mb 16
"""

from __future__ import annotations

import argparse
import os
import resource
import sys
import tempfile
import time
import uuid
from contextlib import suppress
from pathlib import Path

import tomli_w
from fleet_push import ACCESS_KEY, SECRET_KEY, s3_server

from catenary.config import load_settings
from catenary.storage.store import Part, Store, open_store

MB = 1 << 20


class Cut(Exception):
    """The put cut short on purpose."""


def peak_rss_mib(pid: int | None = None) -> float:
    """The peak resident memory of ``pid`` (a child, from ``/proc``) or of this process."""
    if pid is None:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def rclone_pid() -> int:
    """The pid of this process's ``rclone`` child."""
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            text = stat.read_text()
        except OSError:
            continue
        name, rest = text[text.index("(") + 1 : text.rindex(")")], text.rpartition(")")[2]
        if name == "rclone" and int(rest.split()[1]) == os.getpid():
            return int(stat.parent.name)
    raise RuntimeError("no rclone child")


def open_bench_store(folder: Path, endpoint: str, part_mb: int) -> Store:
    config = folder / "store.toml"
    config.write_text(
        tomli_w.dumps(
            {
                "store": {
                    "url": f"s3://bench-{uuid.uuid4().hex[:8]}/fleet",
                    "endpoint": endpoint,
                    "access_key_env": "BENCH_S3_ACCESS_KEY",
                    "secret_key_env": "BENCH_S3_SECRET_KEY",
                    "part_size_mb": part_mb,
                }
            }
        )
    )
    os.environ |= {"BENCH_S3_ACCESS_KEY": ACCESS_KEY, "BENCH_S3_SECRET_KEY": SECRET_KEY}
    return open_store(load_settings(config_path=config))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size-mb", type=int, default=1024, help="the file's size [MiB]")
    parser.add_argument("--part-mb", type=int, default=64, help="the parts' size [MiB]")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="store-parts-") as scratch:
        folder = Path(scratch)
        path = folder / "run.h5"
        with path.open("wb") as out:
            for _ in range(args.size_mb // 64):
                out.write(os.urandom(64 * MB))
            out.write(os.urandom(args.size_mb % 64 * MB))
        size = path.stat().st_size
        with s3_server(folder / "buckets") as endpoint:
            store = open_bench_store(folder, endpoint, args.part_mb)
            sent_at: list[float] = []
            start = time.perf_counter()
            stored = store.put_parts(
                path, "runs/whole.h5", on_part=lambda part: sent_at.append(time.perf_counter())
            )
            end = time.perf_counter()
            assert stored.size_bytes == size
            parts_s, rest_s, total_s = sent_at[-1] - start, end - sent_at[-1], end - start
            print(f"file {size / 1e6:,.0f} MB in {len(sent_at)} parts of {args.part_mb} MiB")
            print(f"  parts sent          {parts_s:6.1f} s  {size / 1e6 / parts_s:6.0f} MB/s")
            print(f"  completed, read back{rest_s:6.1f} s  {size / 1e6 / rest_s:6.0f} MB/s")
            print(f"  whole put           {total_s:6.1f} s  {size / 1e6 / total_s:6.0f} MB/s")
            print(
                f"  peak RSS: this process {peak_rss_mib():.0f} MiB, "
                f"rclone {peak_rss_mib(rclone_pid()):.0f} MiB"
            )

            half = len(sent_at) // 2

            def cut(part: Part) -> None:
                if part.number == half:
                    raise Cut

            with suppress(Cut):
                store.put_parts(path, "runs/cut.h5", on_part=cut)
            parts: list[Part] = []
            start = time.perf_counter()
            store.put_parts(path, "runs/cut.h5", on_part=parts.append)
            resumed_s = time.perf_counter() - start
            sent = sum(part.sent for part in parts)
            print(
                f"resumed after {half} parts: {sent} sent, {len(parts) - sent} found in place, "
                f"{resumed_s:.1f} s"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
