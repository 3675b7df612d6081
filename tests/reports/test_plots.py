"""The plots' decimation: a min/max envelope per pixel column never loses a local minimum."""

from __future__ import annotations

import numpy as np
import pyarrow.parquet as pq
import pytest
from sqlalchemy import create_engine, select
from sqlalchemy.orm import Session

from catenary.config import load_settings
from catenary.measurement.envelope import EnvelopeGrid, envelope, envelope_path
from catenary.measurement.samples import run_samples
from catenary.storage.models import Run
from catenary.storage.store import open_store
from catenary_reports.plots import PLOT_COLUMNS
from catenary_reports.run_report import PANELS, _extent, _grid


def test_one_sample_dip_survives_in_its_column() -> None:
    position = np.linspace(0.0, 100.0, 100_001)  # a sample every millimetre
    values = 12.0 + 0.1 * np.sin(position)
    values[43_210] = 9.5  # a hot spot one sample wide
    values[5] = np.nan
    low, high = envelope(position, values, 0.0, 0.1, 1000)
    assert np.nanmin(low) == 9.5 and int(np.nanargmin(low)) == 432
    assert np.nanmax(high) == pytest.approx(12.1, abs=1e-6)
    x, y = envelope_path(0.0, 0.1, low, high)
    assert np.nanmin(y) == 9.5 and x[np.nanargmin(y)] == pytest.approx(43.25)


def test_empty_columns_break_the_line_once_and_the_end_is_in_the_last_column() -> None:
    position = np.array([0.05, 0.15, 0.55, 1.0])
    values = np.array([1.0, 2.0, 3.0, 4.0])
    low, high = envelope(position, values, 0.0, 0.1, 10)
    assert np.isnan(low[2:5]).all() and low[9] == 4.0  # 1.0 m: the last bin's right end
    _, y = envelope_path(0.0, 0.1, low, high)
    assert np.count_nonzero(np.isnan(y)) == 2  # after bin 1 and after bin 5
    assert not np.isnan(y[0])


def test_batches_and_wires_gather_as_one_array_would() -> None:
    rng = np.random.default_rng(3)
    position = rng.uniform(0.0, 50.0, 20_000)
    wire = rng.integers(0, 2, 20_000)
    values = rng.normal(12.0, 0.3, 20_000)
    grid = EnvelopeGrid(0.0, 0.5, 100, ["t"])
    for part in np.array_split(np.arange(20_000), 7):
        grid.add(position[part], wire[part], {"t": values[part]})
    assert grid.wires == [0, 1]
    for number in (0, 1):
        rows = wire == number
        low, high = envelope(position[rows], values[rows], 0.0, 0.5, 100)
        x, y = grid.series(number, "t", 0, 100)
        expected = envelope_path(0.0, 0.5, low, high)
        np.testing.assert_array_equal(x, expected[0])
        np.testing.assert_array_equal(y, expected[1])


@pytest.mark.slow
@pytest.mark.parametrize("database_url", ["sqlite"], indirect=True)  # the file, not the backend
def test_the_run_reports_envelopes_hold_each_wires_minimum_and_maximum(database: str) -> None:
    with Session(create_engine(database)) as session:
        run = session.scalars(select(Run).where(Run.id == 1)).one()
        samples = run_samples(open_store(load_settings()), run)
    grid, figures = _grid(_extent(samples), 100.0)
    assert figures == 3 and grid.bins == 3 * PLOT_COLUMNS
    table = pq.read_table(samples.store.open_input(samples.key))
    columns = {name: table.column(name).to_numpy() for name in table.column_names}
    good = ~columns["vehicle_fault"]
    assert grid.wires == sorted(set(columns["wire"][good].tolist()))
    for number in grid.wires:
        rows = good & (columns["wire"] == number)
        for quantity, _ in PANELS:
            _, y = grid.series(number, quantity, 0, grid.bins)
            values = columns[quantity][rows]
            assert np.nanmin(y) == np.nanmin(values) and np.nanmax(y) == np.nanmax(values)
