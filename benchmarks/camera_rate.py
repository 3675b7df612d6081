"""Benchmark: recording four GigE Vision line-scan cameras at the train's line rate.

Four of Aravis's fake GigE Vision cameras (``arv-fake-gv-camera-0.8`` processes, one per
loopback address 127.0.0.2-5, with a GenICam description widened to 4096 px) send their own
test pattern (Aravis's diagonal ramp, Mono8) at 5,300 lines/s each: 250 km/h at 13 mm
between lines. The recorder (the ``gige`` source through Aravis into
:func:`catenary.measurement.recording.record_run`, writing the run file as it goes) runs in
a child process at ``nice 10``, so that its own CPU time is measured apart from the cameras'.
The fake cameras cannot be triggered by an encoder and give no CAN bus, so the benchmark
gives every scan the position of an encoder-triggered line (scan index x 13 mm): it measures
rate, not positions.

Reported: scans recorded, each camera's lines lost (scans recorded without its line), the
recorder's CPU time per scan and per camera line, the cameras' CPU time, the file's size.
The target (issue 20): no line lost. Lost lines are told apart by who lost them, from each
fake camera's own log of the frames it sent (``-d stream-thread:2``: a line per frame with
the host's time to the millisecond): lines of frame periods in which the camera sent
nothing ("not sent"), and lines the recorder dropped (frames missing or incomplete, lines
too late); what neither explains is printed as "unexplained".

Aravis 0.8's fake camera oversleeps: whenever its next frame's time passes while it computes
its wait (an unsigned underflow in ``arvgvfakecamera.c``), it waits 100 ms, or until a
control packet arrives, and the frame periods meanwhile are never sent. The benchmark
therefore sends each fake camera a GVCP register read every ``--wake-ms`` (2 ms; from a
socket of its own, which the recorder never sees), which ends such a wait within 2 ms, well
inside a frame period (20 ms); ``--wake-ms 0`` shows the fake cameras as they are. Their
logs are written to memory (``/dev/shm``): a camera whose log line waited for the disk the
run file goes to would miss its frame's time too. And they run at real-time priority
(``chrt -f 10``, as root; ``--no-realtime``): a camera is hardware with its own line clock,
which no program on the host delays, while a fake camera at normal priority waited 30-55 ms
for a core now and then, all four at once, and missed a frame period.

    .venv/bin/python benchmarks/camera_rate.py                  # 20 s at 5,300 lines/s
    .venv/bin/python benchmarks/camera_rate.py --seconds 60 --rate-hz 8000 --width 2048

Needs the ``camera`` extra and the loopback addresses (``.ci/run`` adds them).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import h5py
import numpy as np

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO))

from tests.camera.fakecam import ADDRESSES, missing_addresses, wide_genicam  # noqa: E402

METRES_PER_LINE = 0.013


def child(args: argparse.Namespace) -> None:
    """Record (in the niced child): prints the counts as JSON."""
    from catenary.domain import ScanBlock
    from catenary.measurement.recording import record_run
    from catenary_camera.stream import GigeStream, open_gige

    settings = json.loads(args.child)
    stream = open_gige(settings)

    class EncoderPositions:
        """The stream with positions of encoder-triggered lines (module docstring)."""

        header = stream.header

        def __init__(self, inner: GigeStream) -> None:
            self.inner = inner

        def blocks(self, block_scans: int) -> Iterator[ScanBlock]:
            for block in self.inner.blocks(block_scans):
                index = np.arange(
                    block.first_scan, block.first_scan + block.scans, dtype=np.float64
                )
                yield ScanBlock(
                    block.first_scan,
                    index * METRES_PER_LINE,
                    block.time_s,
                    block.cameras,
                    block.vehicle,
                )

        def close(self) -> None:
            self.inner.close()

    scans = int(args.seconds * args.rate_hz)
    started = time.monotonic()
    try:
        result = record_run(args.out, EncoderPositions(stream), max_scans=scans, block_scans=2048)
    finally:
        stream.close()
    wall_s = time.monotonic() - started
    counts = {name: vars(c) for name, c in stream.counts().items()}
    report = {"scans": result.scans, "wall_s": wall_s, "counts": counts}
    print(json.dumps({**report, "clock_zero_unix_s": stream.clock_zero_unix_s}))
    print(stream.summary(), file=sys.stderr)


def start_cameras(genicam: Path, logs: list[Path], realtime: bool) -> list[subprocess.Popen[bytes]]:
    """The four fake cameras, each logging the frames it sends to its file in ``logs``;
    ``realtime``: at real-time priority (``chrt -f 10``, root only)."""
    priority = ["chrt", "-f", "10"] if realtime else []
    command = [*priority, "arv-fake-gv-camera-0.8", "-g", str(genicam), "-d", "stream-thread:2"]
    cameras = []
    for n, (address, log) in enumerate(zip(ADDRESSES, logs, strict=True), start=1):
        with log.open("wb") as out:
            cameras.append(
                subprocess.Popen(
                    [*command, "-i", address, "-s", f"BENCH{n}"],
                    stdout=out,
                    stderr=subprocess.STDOUT,
                )
            )
    return cameras


GVCP_PORT = 3956
# GVCP READREG_CMD (0x42, flags 0, command 0x0080, 4 bytes, request id) of register 0
READ_VERSION = struct.pack(">BBHHHI", 0x42, 0, 0x0080, 4, 1, 0)


def wake_cameras(interval_s: float, stop: threading.Event) -> None:
    """Until ``stop``: every ``interval_s``, a GVCP register read to each fake camera (from a
    socket of its own: not the recorder's control channel), which ends any wait of its
    streaming thread (see ``--wake-ms``); the replies are read and thrown away."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as udp:
        udp.bind(("127.0.0.1", 0))
        udp.setblocking(False)
        while not stop.wait(interval_s):
            for address in ADDRESSES:
                udp.sendto(READ_VERSION, (address, GVCP_PORT))
            with contextlib.suppress(BlockingIOError):
                while True:
                    udp.recv(64)


SENT = re.compile(rb"^\[(\d\d):(\d\d):(\d\d\.\d+)\].*Send frame \d+$", re.MULTILINE)


def unsent_lines(log: Path, start_unix_s: float, scans: int, rate_hz: float, frame_s: float) -> int:
    """Scans of the run (``scans`` at ``rate_hz`` from ``start_unix_s``) that fall in frame
    periods in which the camera sent no frame, from its log (local times of day, cut to the
    millisecond). Its frame periods are the UNIX clock's (it sends when ``time % period``
    wraps)."""
    day = datetime.fromtimestamp(start_unix_s).replace(hour=0, minute=0, second=0, microsecond=0)
    found = SENT.findall(log.read_bytes())
    sent_s = day.timestamp() + np.array(
        [int(h) * 3600 + int(m) * 60 + float(s) for h, m, s in found]
    )
    # the period each frame was sent in (a logged time is up to 1 ms before the real one)
    sent = np.floor((sent_s + 1e-3) / frame_s).astype(np.int64)
    scan_periods = np.floor((start_unix_s + np.arange(scans) / rate_hz) / frame_s).astype(np.int64)
    return int(np.count_nonzero(~np.isin(scan_periods, sent)))


def cpu_s(pid: int) -> float:
    """User + system CPU time of a running process [s] (``/proc/PID/stat``)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0, help="recording length [s]")
    parser.add_argument("--rate-hz", type=float, default=5300.0, help="line rate per camera")
    parser.add_argument("--width", type=int, default=4096, help="pixels per line")
    parser.add_argument("--lines-per-frame", type=int, default=106, help="lines per frame (Height)")
    parser.add_argument("--packet-size", type=int, default=8192, help="GVSP packet size [B]")
    parser.add_argument(
        "--wake-ms",
        type=float,
        default=2.0,
        help="a register read to each fake camera this often [ms], which ends its oversleep "
        "(module docstring); 0: none",
    )
    parser.add_argument(
        "--realtime",
        action=argparse.BooleanOptionalAction,
        default=True,
        help="run the fake cameras at real-time priority (module docstring; root only)",
    )
    parser.add_argument(
        "--keep", type=Path, help="keep the run file and the cameras' logs in this folder"
    )
    parser.add_argument("--child", help=argparse.SUPPRESS)
    parser.add_argument("--out", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        child(args)
        return 0
    missing = missing_addresses()
    if missing:
        print(f"loopback addresses missing: {', '.join(missing)} (run .ci/run)", file=sys.stderr)
        return 1
    names = [f"cam{n}" for n in range(1, len(ADDRESSES) + 1)]
    realtime = args.realtime and os.geteuid() == 0
    if args.realtime and not realtime:
        print("not root: the fake cameras run at normal priority", file=sys.stderr)
    settings: dict[str, Any] = {
        "cameras": {
            name: {"address": address, "width": args.width}
            for name, address in zip(names, ADDRESSES, strict=True)
        },
        "line_rate_hz": args.rate_hz,
        "lines_per_frame": args.lines_per_frame,
        "packet_size": args.packet_size,
        "buffers": 64,
        "synchronized_clocks": True,  # the fake cameras stamp frames with the host's clock
        "arrival_lag_frames": 0,  # and send each as its first line is taken
    }
    # the cameras' logs in memory (/dev/shm): a line written per frame must not wait for the
    # disk that the run file is being written to
    in_memory = Path("/dev/shm") if Path("/dev/shm").is_dir() else None
    with (
        tempfile.TemporaryDirectory(prefix="camera-rate-") as scratch,
        tempfile.TemporaryDirectory(prefix="camera-rate-logs-", dir=in_memory) as log_dir,
    ):
        tmp = args.keep or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        genicam = wide_genicam(tmp / "fake-wide.xml")
        out = tmp / "run.h5"
        logs = [Path(log_dir) / f"{name}.log" for name in names]
        cameras = start_cameras(genicam, logs, realtime)
        stop_waking = threading.Event()
        if args.wake_ms > 0:
            waking = threading.Thread(target=wake_cameras, args=(args.wake_ms / 1e3, stop_waking))
            waking.start()
        try:
            time.sleep(1.0)  # the cameras bind their sockets
            cameras_cpu = [cpu_s(p.pid) for p in cameras]
            started = time.monotonic()
            recorder = subprocess.Popen(
                [
                    *(sys.executable, __file__, "--child", json.dumps(settings), "--out", str(out)),
                    *(f"--seconds={args.seconds}", f"--rate-hz={args.rate_hz}"),
                ],
                stdout=subprocess.PIPE,
                preexec_fn=lambda: os.nice(10),
            )
            assert recorder.stdout is not None
            report = recorder.stdout.read()
            _, status, usage = os.wait4(recorder.pid, 0)
            wall_s = time.monotonic() - started
            cameras_cpu = [cpu_s(p.pid) - c for p, c in zip(cameras, cameras_cpu, strict=True)]
        finally:
            stop_waking.set()
            for camera in cameras:
                camera.send_signal(signal.SIGINT)
            for camera in cameras:
                camera.wait(timeout=10)
        if status != 0:
            print(f"recorder failed (status {status})", file=sys.stderr)
            return 1
        result = json.loads(report)
        size_mb = out.stat().st_size / 1e6
        with h5py.File(out, "r") as run:  # the scans written (the stream hands out whole blocks)
            # /cameras/{name}/valid is written only if some line is invalid
            lost = [
                int(np.count_nonzero(~run[f"cameras/{name}/valid"][:]))
                if "valid" in run[f"cameras/{name}"]
                else 0
                for name in names
            ]
        scans = result["scans"]
        frame_s = args.lines_per_frame / args.rate_hz
        run = (result["clock_zero_unix_s"], scans, args.rate_hz, frame_s)
        unsent = [unsent_lines(log, *run) for log in logs]
        if args.keep:
            for log in logs:
                shutil.copy(log, args.keep)
    recorder_cpu_s = usage.ru_utime + usage.ru_stime
    waking = f"woken every {args.wake_ms:g} ms" if args.wake_ms > 0 else "not woken"
    print(
        f"4 cameras x {args.width} px, {args.rate_hz:,.0f} lines/s each, "
        f"{args.lines_per_frame} lines per frame, packets of {args.packet_size} B; "
        f"fake cameras {waking}, at {'real-time' if realtime else 'normal'} priority"
    )
    print(
        f"{'camera':8} {'lines':>10} {'lost':>8} {'not sent':>9} {'dropped':>8} "
        f"{'unexplained':>12} {'missing frames':>15} {'incomplete frames':>18} {'resyncs':>8}"
    )
    rows = zip(names, lost, unsent, strict=True)
    for name, lost_lines, not_sent in rows:
        counts = result["counts"][name]
        frames = counts["missing_frames"] + counts["incomplete_frames"]
        dropped = frames * args.lines_per_frame + counts["late_lines"]
        print(
            f"{name:8} {scans - lost_lines:>10,} {lost_lines:>8,} {not_sent:>9,} "
            f"{dropped:>8,} {lost_lines - not_sent - dropped:>12,} "
            f"{counts['missing_frames']:>15,} {counts['incomplete_frames']:>18,} "
            f"{counts['resyncs']:>8,}"
        )
    print(
        f"scans recorded        {scans:,} in {result['wall_s']:.1f} s "
        f"({scans / max(result['wall_s'], 1e-9):,.0f} scans/s; run file {size_mb:,.0f} MB)"
    )
    per_scan_us = recorder_cpu_s / max(scans, 1) * 1e6
    print(
        f"recorder CPU (nice 10) {recorder_cpu_s:.1f} s = {per_scan_us:.1f} "
        f"µs per scan, {per_scan_us / 4:.2f} µs per camera line "
        f"(start-up included; whole child {wall_s:.1f} s)"
    )
    print(f"fake cameras' CPU      {', '.join(f'{c:.1f}' for c in cameras_cpu)} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
