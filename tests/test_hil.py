"""The sensor-mode plant-link codecs (quadsitl/hil.py): frames byte-identical to pymavlink's, units and frames as
PX4's simulators send them, the datagram decoder's round trip, and what it refuses or drops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadsitl import frames, hil, wire
from quadsitl.earth import PX4_HOME

M = wire.mavlink
SYDNEY = (-33.9, 151.2, 20.0)
ALL_FIELDS = hil.ACCEL_UPDATED | hil.GYRO_UPDATED | hil.MAG_UPDATED | hil.BARO_UPDATED


def packed(msg, seq: int, system: int = 1, component: int = wire.PLANT_COMPONENT_ID) -> bytes:
    mav = wire.link(system, component)
    mav.seq = seq
    return msg.pack(mav)


def sensor_frame(buf, seq=0, t=1000, accel=(0.1, -0.2, -9.8), gyro=(0.01, 0.02, -0.03), mag=(0.2, 0.01, 0.43),
                 baro=(955.5, 488.3, 11.9), fields=ALL_FIELDS) -> int:  # fmt: skip
    return hil.encode_sensor(buf, seq, 1, wire.PLANT_COMPONENT_ID, t, accel, gyro, mag, *baro, fields)


def test_hil_sensor_is_byte_identical_to_pymavlink():
    rng = np.random.default_rng(1)
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    for i in range(200):
        v = rng.normal(0.0, 10.0, 13)
        t, fields = int(rng.integers(0, 2**40)), int(rng.integers(0, 2**13))
        n = hil.encode_sensor(buf, i % 256, 1, wire.PLANT_COMPONENT_ID, t, tuple(v[0:3]), tuple(v[3:6]),
                              tuple(v[6:9]), v[9], v[10], v[11], fields)  # fmt: skip
        ref = M.MAVLink_hil_sensor_message(t, *v[0:9], v[9], 0.0, v[10], v[11], fields, 0)
        assert bytes(buf[:n]) == packed(ref, i % 256)


@pytest.mark.parametrize("home", [PX4_HOME, SYDNEY])
def test_hil_gps_is_byte_identical_to_the_python_builder(home):
    rng = np.random.default_rng(2)
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    velocities = [(0.0, 0.0, 0.0), (400.0, -400.0, 500.0), (0.005, -0.015, 0.025), (1.235, -0.5, 0.2)]
    velocities += [tuple(rng.normal(0.0, 5.0, 3)) for _ in range(100)]
    for i, vel in enumerate(velocities):
        pos = (rng.uniform(-5000, 5000), rng.uniform(-5000, 5000), rng.uniform(-100, 100))
        eph, epv = rng.uniform(0, 5), rng.uniform(0, 10)
        n = hil.encode_gps(buf, i % 256, 1, wire.PLANT_COMPONENT_ID, 5000 + i, pos, vel, home, eph, epv, 10)
        ref = wire.hil_gps_message(5000 + i, pos, vel, home, eph, epv, 10)
        assert bytes(buf[:n]) == packed(ref, i % 256), (pos, vel)


def test_the_truth_says_the_state_in_px4s_units():
    s = (12.0, -7.5, -3.25, 1.5, -0.25, 0.5, 0.2, -0.1, 2.0, 0.3, -0.2, 0.1)
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    n = hil.encode_truth(buf, 0, 1, 25, 7000, s, 3.5, (0.5, -1.0, -9.81), PX4_HOME)
    m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
    assert m.get_type() == "HIL_STATE_QUATERNION" and m.time_usec == 7000
    assert np.allclose(m.attitude_quaternion, frames.euler_to_quaternion(*s[6:9]), atol=1e-7)
    p, q, r = frames.euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11])
    assert (m.rollspeed, m.pitchspeed, m.yawspeed) == pytest.approx((p, q, r), abs=1e-6)
    lat, lon = frames.ned_to_geodetic(s[0], s[1], PX4_HOME[0], PX4_HOME[1])
    assert (m.lat, m.lon, m.alt) == (round(lat * 1e7), round(lon * 1e7), round((PX4_HOME[2] + 3.25) * 1000))
    assert (m.vx, m.vy, m.vz) == (150, -25, 50)  # cm/s
    assert m.ind_airspeed == m.true_airspeed == 350
    assert (m.xacc, m.yacc, m.zacc) == (round(0.5 / 9.80665e-3), round(-1.0 / 9.80665e-3), round(-9.81 / 9.80665e-3))
    n = hil.encode_truth(buf, 0, 1, 25, 7000, s, 3.5, (0.0, 0.0, -1e4), PX4_HOME)
    assert wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0].zacc == -32768  # int16 saturates


def datagram(gps: bool = True, truth: bool = True, fields: int = ALL_FIELDS, **sensor) -> np.ndarray:
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    n = sensor_frame(buf, fields=fields, **sensor)
    if gps:
        n += hil.encode_gps(buf[n:], 1, 1, 25, 880, (12.3, -4.5, -3.2), (1.23, -0.5, 0.2), PX4_HOME, 1.0, 2.0, 10)
    if truth:
        s = (1.0, 2.0, -3.0, 0.1, 0.2, -0.3, 0.1, -0.2, 1.0, 0.01, 0.02, 0.03)
        n += hil.encode_truth(buf[n:], 2, 1, 25, 1000, s, 2.0, (0.0, 0.0, -9.8), PX4_HOME)
    return buf[:n].copy()


def decode(d: np.ndarray, z: np.ndarray | None = None):
    z = np.zeros(hil.Z_SIZE) if z is None else z
    truth, frame = np.zeros(hil.TRUTH_DECODED), np.zeros(wire.FRAME_MAX, dtype=np.uint8)
    t, flags, dropped = hil.decode_sensors(d, len(d), PX4_HOME, z, truth, frame)
    return t, flags, dropped, z, truth


def test_a_tick_datagram_decodes_to_the_estimators_measurements_and_the_truth():
    d = datagram()
    assert len(d) <= hil.DATAGRAM_MAX
    t, flags, dropped, z, truth = decode(d)
    assert (t, flags, dropped) == (1000, hil.MAG_NEW | hil.BARO_NEW | hil.GPS_NEW, 0)
    f32 = np.float32
    assert list(z[hil.Z_ACCEL : hil.Z_ACCEL + 3]) == [f32(0.1), f32(-0.2), f32(-9.8)]
    assert list(z[hil.Z_GYRO : hil.Z_GYRO + 3]) == [f32(0.01), f32(0.02), f32(-0.03)]
    assert list(z[hil.Z_MAG : hil.Z_MAG + 3]) == [f32(0.2), f32(0.01), f32(0.43)]
    assert z[hil.Z_BARO] == f32(488.3)  # pressure altitude [m AMSL]
    assert np.allclose(z[hil.Z_GPS_POS : hil.Z_GPS_POS + 3], (12.3, -4.5, -3.2), atol=(0.006, 0.006, 6e-4))
    assert np.allclose(z[hil.Z_GPS_VEL : hil.Z_GPS_VEL + 3], (1.23, -0.5, 0.2), atol=5e-3)
    s = (1.0, 2.0, -3.0, 0.1, 0.2, -0.3, 0.1, -0.2, 1.0, 0.01, 0.02, 0.03)
    assert np.allclose(truth[:3], s[:3], atol=0.006) and np.allclose(truth[3:6], s[3:6], atol=0.005)
    assert np.allclose(truth[6:12], s[6:12], atol=1e-6)
    assert np.allclose(truth[12:15], frames.euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11]), atol=1e-6)


def test_only_what_fields_updated_says_is_new():
    for fields, expected in ((hil.ACCEL_UPDATED | hil.GYRO_UPDATED, 0), (hil.MAG_UPDATED, hil.MAG_NEW),
                             (hil.BARO_UPDATED, hil.BARO_NEW), (0b110000000, 0)):  # fmt: skip
        t, flags, _, _, truth = decode(datagram(gps=False, truth=False, fields=fields))
        assert (t, flags) == (1000, expected)
        assert np.isnan(truth).all()  # no truth frame: NaN


def test_corrupt_foreign_truncated_and_signed_datagrams_are_refused():
    d = datagram()
    for at in (12, len(d) // 2, len(d) - 20):
        bad = d.copy()
        bad[at] ^= 0xFF
        assert decode(bad)[0] == wire.BAD_CRC
    heartbeat = np.frombuffer(packed(M.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3), 0), dtype=np.uint8)
    assert decode(np.concatenate([d, heartbeat]))[0] == wire.NOT_THIS_FRAME
    only_gps = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    n = hil.encode_gps(only_gps, 0, 1, 25, 0, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), PX4_HOME, 1.0, 1.0, 10)
    assert decode(only_gps[:n])[0] == wire.NOT_THIS_FRAME  # no HIL_SENSOR
    assert decode(d[:-5])[0] == wire.NOT_THIS_FRAME  # the last frame cut short
    signed = d.copy()
    signed[2] = 1  # incompat flags: signed
    assert decode(signed)[0] == wire.NOT_THIS_FRAME


def test_non_finite_samples_are_dropped_and_counted():
    z = np.full(hil.Z_SIZE, 7.0)
    t, flags, dropped, z, _ = decode(datagram(gps=False, accel=(math.nan, 0.0, -9.8)), z)
    assert t == 1000 and dropped & hil.IMU_DROPPED
    assert (z[hil.Z_ACCEL : hil.Z_ACCEL + 3] == 7.0).all() and (z[hil.Z_GYRO : hil.Z_GYRO + 3] == 7.0).all()
    _, flags, dropped, _, _ = decode(datagram(gps=False, mag=(0.2, math.inf, 0.4)))
    assert dropped & hil.MAG_DROPPED and not flags & hil.MAG_NEW
    _, flags, dropped, _, _ = decode(datagram(gps=False, baro=(955.0, math.inf, 11.0)))
    assert dropped & hil.BARO_DROPPED and not flags & hil.BARO_NEW


def test_a_gps_without_a_3d_fix_is_not_used():
    d = datagram(gps=False, truth=False)
    no_fix = M.MAVLink_hil_gps_message(0, 2, 473977420, 85455940, 488000, 100, 200, 0, 0, 0, 0, 65535, 10)
    both = np.concatenate([d, np.frombuffer(packed(no_fix, 1), dtype=np.uint8)])
    assert decode(both)[1] & hil.GPS_NEW == 0
