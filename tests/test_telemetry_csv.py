"""The telemetry CSV read back as written: every column by name, NaN (``nan``) kept, a lone row and a flight
with no rows (a header alone) as arrays of their length, and sensor mode's and a battery's columns when there
are some."""

from __future__ import annotations

import numpy as np

from groundstation.telemetry_csv import BATTERY_COLUMNS, COLUMNS, SENSING_COLUMNS, read_csv, write_csv


def test_what_write_csv_writes_read_csv_reads_column_by_column(tmp_path):
    rng = np.random.default_rng(3)
    for n, columns in (
        (500, COLUMNS),
        (1, COLUMNS),
        (7, COLUMNS + SENSING_COLUMNS),
        (3, COLUMNS + SENSING_COLUMNS + BATTERY_COLUMNS),
        (2, COLUMNS + BATTERY_COLUMNS),
    ):
        rows = rng.normal(size=(n, len(columns))) * 10.0 ** rng.integers(-9, 4, size=len(columns))
        rows[:, COLUMNS.index("x_ref")] = np.nan  # attitude setpoints: nothing controls x and y
        write_csv(tmp_path / "t.csv", rows)
        data = read_csv(tmp_path / "t.csv")
        assert list(data) == list(columns)
        for i, name in enumerate(columns):
            assert data[name].shape == (n,) and data[name].flags.c_contiguous
            np.testing.assert_allclose(data[name], rows[:, i], rtol=1e-11, atol=0)  # %.12g
        assert np.isnan(data["x_ref"]).all()


def test_a_flight_with_no_rows_reads_as_empty_columns(tmp_path):
    write_csv(tmp_path / "t.csv", np.zeros((0, len(COLUMNS))))
    data = read_csv(tmp_path / "t.csv")
    assert list(data) == list(COLUMNS) and all(v.shape == (0,) for v in data.values())
