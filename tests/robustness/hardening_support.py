"""What the field-length, read-only, disk-full and hostile-name cases share: counts of what a
database holds, and what makes a child ``catenary`` run under a file size limit or without
root's file access (``catenary(..., preexec_fn=...)``)."""

from __future__ import annotations

import ctypes
import os
import resource
import signal
from collections.abc import Callable

from sqlalchemy import Engine, func, select

from catenary.storage.models import Base


def row_counts(engine: Engine) -> dict[str, int]:
    """The rows of every table of the models, by table name."""
    with engine.connect() as connection:
        return {
            name: int(connection.scalar(select(func.count()).select_from(table)) or 0)
            for name, table in Base.metadata.tables.items()
        }


def file_size_limit(limit_bytes: int) -> Callable[[], None]:
    """A child may write no file past ``limit_bytes`` (``RLIMIT_FSIZE``, with SIGXFSZ ignored so
    that a write past it fails with EFBIG, as on a full disk)."""

    def limit() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit_bytes, limit_bytes))

    return limit


_PR_CAPBSET_DROP = 24
# CAP_DAC_OVERRIDE, CAP_DAC_READ_SEARCH, CAP_FOWNER: what lets root ignore a file's permissions
_FILE_ACCESS_CAPABILITIES = (1, 2, 3)


def without_root_file_access() -> None:
    """In a child: when running as root, drop the capabilities that let root write what its
    permissions forbid (from the bounding set, so that the command it starts has none of them);
    the child then meets a file's permission bits as its owner does. Nothing to do for others.
    """
    if os.geteuid() != 0:
        return
    libc = ctypes.CDLL(None, use_errno=True)
    for capability in _FILE_ACCESS_CAPABILITIES:
        if libc.prctl(_PR_CAPBSET_DROP, capability, 0, 0, 0) != 0:
            raise OSError(ctypes.get_errno(), f"prctl(PR_CAPBSET_DROP, {capability})")
