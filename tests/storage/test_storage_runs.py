"""Finding runs by id, UUID, UUID prefix or ``latest``."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

import pytest
from sqlalchemy import Engine

from catenary.errors import UserError
from catenary.storage.database import session_scope
from catenary.storage.runs import find_run


def test_a_run_is_found_by_id_uuid_prefix_or_latest(migrated: Engine, build: Any) -> None:
    with session_scope(migrated) as session:
        first = build.run(session, uuid="0a1b2c3d-0000-5000-8000-000000000001")
        second = build.run(
            session,
            line=first.line,
            track=first.track,
            vehicle=first.vehicle,
            rig_calibration=first.rig_calibration,
            source_sha256="e" * 64,
            uuid="0a1b9999-0000-5000-8000-000000000002",
            processed_at=build.T0 + timedelta(hours=1),
        )
        ids = first.id, second.id
    with session_scope(migrated) as session:
        assert find_run(session, str(ids[0])).id == ids[0]
        assert find_run(session, "0a1b2c3d-0000-5000-8000-000000000001").id == ids[0]
        assert find_run(session, "0A1B2C").id == ids[0]  # a prefix, in either case
        assert find_run(session, "0a1b99").id == ids[1]
        assert find_run(session, "latest").id == ids[1]  # processed last
        with pytest.raises(UserError, match="several runs' UUIDs begin so"):
            find_run(session, "0a1b")
        with pytest.raises(UserError, match=r"^no run 77 in the database$"):
            find_run(session, "77")
        with pytest.raises(UserError, match=r"^no run ffff in the database$"):
            find_run(session, "ffff")
        for wrong in ("0a1", "run-1", ""):
            with pytest.raises(UserError, match="give a run id"):
                find_run(session, wrong)
