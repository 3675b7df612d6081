"""A run's blocks staged in worker processes (``catenary process --workers N``).

A ``StagedProcessor``'s ``stage`` (stateless: its result depends on the block alone) runs in
a pool of worker processes, each of which opens the run file itself and reads the camera
lines of the blocks it is given. What crosses between the processes is the stage, once per
worker, a block's scan positions, times and vehicle sensors (tens of kilobytes) and the
stage's result: never the camera lines, so nothing of the run is pickled. The main process
reads those small series, keeps at most ``IN_FLIGHT_PER_WORKER`` blocks per worker in
flight (memory stays flat whatever the run's length) and takes the staged blocks in run
order. Workers are forked by a fork server that has imported this module and the stage's
(``forkserver``, preloaded): nothing of the main process (its open HDF5 file, its threads) is
inherited, and the imports are paid once, not per worker. Other work that needs the run file
alone runs the same way (``with_run``: the image evidence's crops, cut and encoded in the
workers, only the PNGs coming back).

The workers end with the main process, however it ends (SIGKILL included): each holds the
reading end of a pipe whose only writing end is the main process's, and a thread of the
worker ends it as soon as that pipe reads as closed. The fork server then ends too (CPython's
ends when the last process holding its "alive" pipe, the main process or a worker, is gone),
and so does the resource tracker: nothing of the command is left holding its standard output
and error, which reach end-of-file at once for whoever reads them.
"""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import warnings
from collections import deque
from collections.abc import Callable, Generator, Iterable, Iterator
from concurrent.futures import Future, ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import replace
from functools import partial
from multiprocessing.connection import Connection
from pathlib import Path
from types import FrameType
from typing import Any, TypeVar

from catenary.domain import ScanBlock
from catenary.measurement.runfile import RunFile, RunFileWarning, open_run

__all__ = [
    "IN_FLIGHT_PER_WORKER",
    "default_workers",
    "interruptions_held",
    "staged_blocks",
    "with_run",
]

T = TypeVar("T")
R = TypeVar("R")

IN_FLIGHT_PER_WORKER = 2
"""Blocks (or other items) submitted and not yet taken, per worker: enough to keep every
worker busy while the main process takes a block."""


def default_workers() -> int:
    """The cores this process may run on (its CPU affinity; else the machine's cores)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@contextmanager
def interruptions_held() -> Iterator[None]:
    """SIGINT and SIGTERM received during the block are raised again when it ends, for the
    handlers that were there. (Python runs signal handlers in the main thread only: in another
    thread there is nothing to hold.)"""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received: list[int] = []

    def hold(signum: int, frame: FrameType | None) -> None:
        received.append(signum)

    previous = {number: signal.signal(number, hold) for number in _INTERRUPTIONS}
    try:
        yield
    finally:
        for number, handler in previous.items():
            signal.signal(number, handler)
        for signum in dict.fromkeys(received):
            signal.raise_signal(signum)


_INTERRUPTIONS = (signal.SIGINT, signal.SIGTERM)

_worker: tuple[Callable[[ScanBlock], Any] | None, RunFile] | None = None


def _start_worker(
    stage: Callable[[ScanBlock], Any] | None, run_path: Path, lifeline: Connection
) -> None:
    """A worker's start: the stage (if any), the run file open, and a thread ending the
    worker when the main process's end of ``lifeline`` closes."""
    global _worker
    # the main process takes Ctrl-C and ends the pool; the run's warnings it has given
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    warnings.simplefilter("ignore", RunFileWarning)
    threading.Thread(target=_end_with, args=(lifeline,), name="lifeline", daemon=True).start()
    _worker = stage, open_run(run_path)


def _end_with(lifeline: Connection) -> None:
    """In a worker: wait until ``lifeline`` reads as closed (the main process, which holds
    its only writing end and never writes, has ended), then end this process at once."""
    lifeline.poll(None)
    os._exit(1)


def _stage_block(block: ScanBlock) -> Any:
    """In a worker: the stage of ``block`` (without camera lines), its lines read here."""
    assert _worker is not None
    stage, run = _worker
    assert stage is not None
    lines = run.camera_lines(block.first_scan, block.first_scan + block.scans)
    return stage(replace(block, cameras=lines))


def _with_run(call: Callable[[RunFile, Any], Any], item: Any) -> Any:
    """In a worker: ``call(run, item)`` with the worker's run file."""
    assert _worker is not None
    return call(_worker[1], item)


def staged_blocks(
    run_path: Path,
    stage: Callable[[ScanBlock], Any],
    blocks: Iterable[ScanBlock],
    workers: int,
) -> Generator[tuple[ScanBlock, Future[Any]], None, None]:
    """Each of ``blocks`` (of the run file ``run_path``, without camera lines: read by the
    workers), in order, with the future of its ``stage`` in a pool of ``workers`` processes.
    Closing the iterator (``contextlib.closing``) cancels the blocks not started and ends
    the pool; the workers end with this process, however it ends (module docstring)."""
    return _in_order(run_path, stage, _stage_block, type(stage).__module__, blocks, workers)


def with_run(
    run_path: Path,
    call: Callable[[RunFile, T], R],
    items: Iterable[T],
    workers: int,
) -> Generator[tuple[T, Future[R]], None, None]:
    """Each of ``items``, in order, with the future of ``call(run, item)`` (``call``: a
    module's function; ``run``: the run file ``run_path`` open) in a pool of ``workers``
    processes; closing the iterator ends the pool, as for ``staged_blocks``."""
    return _in_order(run_path, None, partial(_with_run, call), call.__module__, items, workers)


def _in_order(
    run_path: Path,
    stage: Callable[[ScanBlock], Any] | None,
    task: Callable[[T], R],
    module: str,
    items: Iterable[T],
    workers: int,
) -> Generator[tuple[T, Future[R]], None, None]:
    """Each of ``items``, in order, with the future of ``task(item)`` in a pool of
    ``workers`` processes started with ``stage`` and the run file (``_start_worker``), at
    most ``IN_FLIGHT_PER_WORKER`` per worker submitted and not yet taken; ``module``, that
    of the work, is imported by the fork server (if it starts here) for every worker."""
    context = multiprocessing.get_context("forkserver")
    context.set_forkserver_preload([__name__, module])
    lifeline, held = context.Pipe(duplex=False)  # ``held``: the only writing end, kept here
    pool = ProcessPoolExecutor(
        workers,
        mp_context=context,
        initializer=_start_worker,
        initargs=(stage, run_path, lifeline),
    )
    try:
        pending: deque[tuple[T, Future[R]]] = deque()
        for item in items:
            # a worker that ``submit`` starts is then known to the pool, which ends it: one
            # interrupted while the fork server forks it would outlive this process's
            # semaphores and fail to start, printing a traceback to the command's output
            with interruptions_held():
                future = pool.submit(task, item)
            pending.append((item, future))
            if len(pending) >= IN_FLIGHT_PER_WORKER * workers:
                yield pending.popleft()
        while pending:
            yield pending.popleft()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        lifeline.close()
        held.close()
