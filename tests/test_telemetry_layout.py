"""The telemetry records' layouts are declared once (quadsitl.telemetry.STREAMS, FIELDS): every field's offset, the
numpy type the logger and the dashboard read records with, and the compiled tick's writes come from there."""

from __future__ import annotations

import numpy as np
import pytest

from quadsitl import telemetry


@pytest.mark.parametrize("stream", list(telemetry.STREAMS))
def test_a_record_packed_by_its_struct_reads_back_field_by_field_through_its_numpy_type(stream):
    fields = telemetry.FIELDS[stream]
    battery = [15.5, 18.25, 120.0, 9000.0, 0.75]  # the status record's battery (V, A, mAh, J, share left)
    values = [7, 0.25] + ([1, 4, 2, -3, *battery] if stream == "status" else [i + 0.5 for i in range(len(fields) - 2)])
    record = telemetry.STREAMS[stream].pack(*values)
    read = np.frombuffer(record, dtype=telemetry.record_dtype(stream))[0]
    assert [read[f] for f in fields] == values
    for field, value in zip(fields, values):  # each field where OFFSETS says
        kind = telemetry.record_dtype(stream).fields[field][0]
        at = telemetry.OFFSETS[stream][field]
        assert np.frombuffer(record[at : at + kind.itemsize], dtype=kind)[0] == value


def test_the_writers_offsets_are_the_layouts():
    o = telemetry.OFFSETS
    assert (o["status"]["tick"], o["status"]["t"]) == (telemetry.AT_TICK, telemetry.AT_T)
    assert o["state"]["x"] + 9 * telemetry.FLOAT64 == telemetry.STATE_AT_P  # x..yaw, then p, q, r
    assert telemetry.STATUS_AT_BATTERY - 8 == telemetry.STATUS_AT_OFFBOARD_TICK  # then the battery's 5 float64s
    assert telemetry.STREAMS["status"].size - 5 * telemetry.FLOAT64 == telemetry.STATUS_AT_BATTERY
