"""Query results as NumPy columns: the same arrays on both backends, NULLs refused."""

from __future__ import annotations

import numpy as np
import pytest
from sqlalchemy import BigInteger, Engine, Float, Integer, String, cast, func, literal, select

from catenary.storage.columns import fetch_columns
from catenary.storage.database import session_scope
from catenary.storage.models import Mast

from .conftest import Fleet


def test_columns_of_every_row(engine: Engine) -> None:
    with session_scope(engine) as session:
        Fleet(session).track(masts=5)
        query = select(
            Mast.id,
            cast(Mast.chainage_m * 2, Float).label("double_m"),
            cast(func.length(Mast.code), BigInteger).label("length"),
        ).order_by(Mast.id)
        columns = fetch_columns(session.connection(), query)
    assert list(columns) == ["id", "double_m", "length"]
    assert columns["id"].dtype == np.int64 and columns["double_m"].dtype == np.float64
    assert sorted(columns["double_m"].tolist()) == [2000.0, 2100.0, 2200.0, 2300.0, 2400.0]
    assert columns["length"].tolist() == [3] * 5


def test_nulls_and_other_types_are_refused(engine: Engine) -> None:
    with session_scope(engine) as session:
        Fleet(session).track(masts=2)
        nulls = select(Mast.id, cast(Mast.anchor_section, Integer).label("section"))
        with pytest.raises(ValueError, match="NULL"):
            fetch_columns(session.connection(), nulls)
        with pytest.raises(TypeError, match="Integer, BigInteger and Float"):
            fetch_columns(session.connection(), select(cast(literal("x"), String).label("x")))
