"""The sensor-mode plant-link codecs (quadsitl/hil.py): frames byte-identical to pymavlink's, units and frames as
PX4's simulators send them, the datagram decoder's round trip, and what it refuses or drops."""

from __future__ import annotations

import math

import numpy as np
import pytest

from quadsitl import codec, frames, hil, wire
from quadsitl.frames import PX4_HOME

M = wire.mavlink
SYDNEY = (-33.9, 151.2, 20.0)
HOMES = (PX4_HOME, SYDNEY)
SYS, COMP = wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID
ALL_FIELDS = hil.ACCEL_UPDATED | hil.GYRO_UPDATED | hil.MAG_UPDATED | hil.BARO_UPDATED
# Half a quantum of HIL_GPS / HIL_STATE_QUATERNION (plus float slack): lat/lon 1e-7 deg, alt 1 mm, speeds 1 cm/s.
HALF_LATLON_M = 0.5e-7 * math.pi / 180.0 * frames.EARTH_RADIUS + 1e-6
HALF_MM = 0.5e-3 + 1e-9
HALF_CM = 0.5e-2 + 1e-9


def packed(msg, seq: int, system: int = SYS, component: int = COMP) -> bytes:
    mav = wire.link(system, component)
    mav.seq = seq
    return msg.pack(mav)


def as_array(data: bytes) -> np.ndarray:
    return np.frombuffer(data, dtype=np.uint8).copy()


def new_buf() -> np.ndarray:
    return np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)


# ---- the encoders against pymavlink -------------------------------------------------------------------------


def test_hil_sensor_is_byte_identical_to_pymavlink():
    rng = np.random.default_rng(1)
    buf = new_buf()
    cases = [(0, np.zeros(12), 0), (2**40, np.full(12, 0.1), 0xFFFFFFFF), (2**40 - 1, np.arange(12.0), ALL_FIELDS)]
    for _ in range(300):
        v = rng.normal(0.0, 10.0, 12)
        if rng.random() < 0.3:
            v = v.astype(np.float32).astype(np.float64)  # exactly representable in float32 as well
        cases.append((int(rng.integers(0, 2**40 + 1)), v, int(rng.integers(0, 2**32))))
    for i, (t, v, fields) in enumerate(cases):
        seq, system, component = i % 256, 1 + i % 5, COMP + i % 3
        n = hil.encode_sensor(buf, seq, system, component, t, tuple(v[0:3]), tuple(v[3:6]), tuple(v[6:9]), v[9],
                              v[10], v[11], fields)  # fmt: skip
        ref = M.MAVLink_hil_sensor_message(t, *v[0:9], v[9], 0.0, v[10], v[11], fields, 0)
        assert bytes(buf[:n]) == packed(ref, seq, system, component), (t, v, fields)


@pytest.mark.parametrize("home", HOMES)
def test_hil_gps_is_byte_identical_to_the_python_builder(home):
    rng = np.random.default_rng(2)
    buf = new_buf()
    velocities = [
        (0.0, 0.0, 0.0),  # course unknown (65535)
        (0.004, -0.004, 0.0),  # below 1 cm/s over ground: course unknown too
        (327.67, -327.67, 327.67),  # the int16 limits exactly
        (327.68, -327.69, 500.0),  # saturated
        (-400.0, 400.0, -1000.0),  # saturated the other way, ground speed 565.69 m/s
        (0.125, -0.375, 0.625),  # x.5 cm/s exactly: ties go to even, as Python's round
        (0.005, -0.015, 0.025),
        (1.235, -0.5, 0.2),
        (-2.5, 0.0, 0.0),  # due south: 18000 cdeg
        (0.0, -3.0, 0.0),  # due west: 27000 cdeg
    ]
    velocities += [tuple(rng.normal(0.0, 5.0, 3)) for _ in range(150)]
    velocities += [tuple(np.round(rng.normal(0.0, 500.0, 3)) / 200.0) for _ in range(50)]  # many x.5 cm/s
    for i, vel in enumerate(velocities):
        pos = (rng.uniform(-5000, 5000), rng.uniform(-5000, 5000), rng.uniform(-100, 100))
        if i % 10 == 0:
            pos = (0.0, 0.0, 0.0)
        eph, epv = rng.uniform(0, 5), rng.uniform(0, 10)
        t, sats, seq = int(rng.integers(0, 2**40)), int(rng.integers(0, 30)), i % 256
        n = hil.encode_gps(buf, seq, SYS, COMP, t, pos, vel, home, eph, epv, sats)
        ref = wire.hil_gps_message(t, pos, vel, home, eph, epv, sats)
        assert bytes(buf[:n]) == packed(ref, seq), (pos, vel)
        m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
        assert m.fix_type == 3 and m.satellites_visible == sats and m.time_usec == t


def test_hil_gps_course_is_unknown_at_zero_speed_and_velocities_saturate():
    buf = new_buf()
    n = hil.encode_gps(buf, 0, SYS, COMP, 1, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), PX4_HOME, 1.0, 1.0, 9)
    m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
    assert (m.cog, m.vel, m.vn, m.ve, m.vd) == (65535, 0, 0, 0, 0)
    n = hil.encode_gps(buf, 0, SYS, COMP, 1, (0.0, 0.0, 0.0), (400.0, -400.0, 0.125), PX4_HOME, 1.0, 1.0, 9)
    m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
    assert (m.vn, m.ve, m.vd) == (32767, -32768, 12)
    assert m.cog == 31500 and m.vel == round(math.hypot(400.0, 400.0) * 100)


@pytest.mark.parametrize("home", HOMES)
def test_the_truth_says_the_state_in_px4s_units(home):
    rng = np.random.default_rng(3)
    buf = new_buf()
    for i in range(100):
        s = (*rng.uniform(-5000, 5000, 2), rng.uniform(-100, 100), *rng.normal(0, 5, 3),
             rng.uniform(-3, 3), rng.uniform(-1.3, 1.3), rng.uniform(-3, 3), *rng.normal(0, 1, 3))  # fmt: skip
        airspeed, force, t = rng.uniform(0, 30), tuple(rng.normal(0, 10, 3)), int(rng.integers(0, 2**40))
        n = hil.encode_truth(buf, i % 256, SYS, COMP, t, s, airspeed, force, home)
        m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
        assert m.get_type() == "HIL_STATE_QUATERNION" and m.time_usec == t
        assert (m.get_header().seq, m.get_srcSystem(), m.get_srcComponent()) == (i % 256, SYS, COMP)
        q = frames.euler_to_quaternion(*s[6:9])
        assert list(m.attitude_quaternion) == [np.float32(c) for c in q]
        p, qr, r = frames.euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11])
        assert (m.rollspeed, m.pitchspeed, m.yawspeed) == (np.float32(p), np.float32(qr), np.float32(r))
        lat, lon = frames.ned_to_geodetic(s[0], s[1], home[0], home[1])
        assert (m.lat, m.lon, m.alt) == (round(lat * 1e7), round(lon * 1e7), round((home[2] - s[2]) * 1000))
        assert (m.vx, m.vy, m.vz) == (round(s[3] * 100), round(s[4] * 100), round(s[5] * 100))  # cm/s
        assert m.ind_airspeed == m.true_airspeed == round(airspeed * 100)  # cm/s
        assert (m.xacc, m.yacc, m.zacc) == tuple(round(f / 9.80665e-3) for f in force)  # mG


def test_the_truth_saturates_int16_fields():
    buf = new_buf()
    s = (0.0, 0.0, 0.0, 400.0, -400.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    n = hil.encode_truth(buf, 0, SYS, COMP, 1, s, 3.5, (1e4, -1e4, -9.80665), PX4_HOME)
    m = wire.link(2, 1).parse_buffer(bytes(buf[:n]))[0]
    assert (m.xacc, m.yacc, m.zacc) == (32767, -32768, -1000)
    assert (m.vx, m.vy, m.vz) == (32767, -32768, 50)
    assert m.ind_airspeed == m.true_airspeed == 350
    assert m.attitude_quaternion == [1.0, 0.0, 0.0, 0.0] and (m.lat, m.lon) == (473977420, 85455940)


# ---- the datagram decoder ------------------------------------------------------------------------------------


def sensor_frame(buf, seq=0, t=1000, accel=(0.1, -0.2, -9.8), gyro=(0.01, 0.02, -0.03), mag=(0.2, 0.01, 0.43),
                 baro=(955.5, 488.3, 11.9), fields=ALL_FIELDS) -> int:  # fmt: skip
    return hil.encode_sensor(buf, seq, SYS, COMP, t, accel, gyro, mag, *baro, fields)


GPS_POS, GPS_VEL = (12.3, -4.5, -3.2), (1.23, -0.5, 0.2)
STATE = (1.0, 2.0, -3.0, 0.1, 0.2, -0.3, 0.1, -0.2, 1.0, 0.01, 0.02, 0.03)


def datagram(gps=True, truth=True, home=PX4_HOME, gps_pos=GPS_POS, gps_vel=GPS_VEL, state=STATE, **sensor):
    """The frames of one tick concatenated; returns (datagram, where each frame starts and ends)."""
    buf = new_buf()
    n = sensor_frame(buf, **sensor)
    bounds = [(0, n)]
    if gps:
        n += hil.encode_gps(buf[n:], 1, SYS, COMP, 880, gps_pos, gps_vel, home, 1.0, 2.0, 10)
        bounds.append((bounds[-1][1], n))
    if truth:
        n += hil.encode_truth(buf[n:], 2, SYS, COMP, 1000, state, 2.0, (0.5, -0.25, -9.8), home)
        bounds.append((bounds[-1][1], n))
    assert n <= hil.DATAGRAM_MAX
    return buf[:n].copy(), bounds


def decode(d, z=None, home=PX4_HOME):
    z = np.zeros(hil.Z_SIZE) if z is None else z
    truth, frame = np.zeros(hil.TRUTH_DECODED), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    t, flags, dropped = hil.decode_sensors(d, len(d), home, z, truth, frame)
    return t, flags, dropped, z, truth


def test_a_tick_datagram_decodes_to_the_estimators_measurements_and_the_truth():
    d, _ = datagram()
    t, flags, dropped, z, truth = decode(d)
    assert (t, flags, dropped) == (1000, hil.IMU_NEW | hil.MAG_NEW | hil.BARO_NEW | hil.GPS_NEW, 0)
    f32 = np.float32
    assert list(z[hil.Z_ACCEL : hil.Z_ACCEL + 3]) == [f32(0.1), f32(-0.2), f32(-9.8)]
    assert list(z[hil.Z_GYRO : hil.Z_GYRO + 3]) == [f32(0.01), f32(0.02), f32(-0.03)]
    assert list(z[hil.Z_MAG : hil.Z_MAG + 3]) == [f32(0.2), f32(0.01), f32(0.43)]
    assert z[hil.Z_BARO] == f32(488.3)  # the pressure altitude [m AMSL], not the pressure
    assert np.allclose(z[hil.Z_GPS_POS : hil.Z_GPS_POS + 3], GPS_POS, rtol=0, atol=HALF_LATLON_M)
    assert abs(z[hil.Z_GPS_POS + 2] - GPS_POS[2]) <= HALF_MM
    assert np.allclose(z[hil.Z_GPS_VEL : hil.Z_GPS_VEL + 3], GPS_VEL, rtol=0, atol=HALF_CM)
    assert z[hil.Z_GPS_TIME] == 880  # when the fix was measured [µs]: HIL_GPS's time_usec, before the tick's 1000
    assert np.allclose(truth[0:6], STATE[0:6], rtol=0, atol=HALF_CM)
    assert np.allclose(truth[6:12], STATE[6:12], rtol=0, atol=1e-6)


@pytest.mark.parametrize("home", HOMES)
def test_random_datagrams_round_trip(home):
    rng = np.random.default_rng(4)
    for _ in range(200):
        t = int(rng.integers(0, 2**40 + 1))
        accel, gyro, mag = (tuple(rng.normal(0, sd, 3)) for sd in (10.0, 2.0, 0.5))
        baro = (rng.uniform(800, 1100), rng.uniform(-100, 3000), rng.uniform(-20, 40))
        gps_pos = (*rng.uniform(-5000, 5000, 2), rng.uniform(-100, 100))
        gps_vel = tuple(rng.normal(0, 10, 3))
        s = (*rng.uniform(-5000, 5000, 2), rng.uniform(-100, 100), *rng.normal(0, 5, 3),
             rng.uniform(-3, 3), rng.uniform(-1.2, 1.2), rng.uniform(-3, 3), *rng.normal(0, 1, 3))  # fmt: skip
        d, _ = datagram(home=home, gps_pos=gps_pos, gps_vel=gps_vel, state=s, t=t, accel=accel, gyro=gyro, mag=mag,
                        baro=baro)  # fmt: skip
        got_t, flags, dropped, z, truth = decode(d, home=home)
        assert (got_t, flags, dropped) == (t, hil.IMU_NEW | hil.MAG_NEW | hil.BARO_NEW | hil.GPS_NEW, 0)
        f32 = np.float32
        assert list(z[hil.Z_ACCEL : hil.Z_ACCEL + 3]) == [f32(v) for v in accel]
        assert list(z[hil.Z_GYRO : hil.Z_GYRO + 3]) == [f32(v) for v in gyro]
        assert list(z[hil.Z_MAG : hil.Z_MAG + 3]) == [f32(v) for v in mag]
        assert z[hil.Z_BARO] == f32(baro[1])
        assert np.abs(z[hil.Z_GPS_POS : hil.Z_GPS_POS + 2] - gps_pos[:2]).max() <= HALF_LATLON_M
        assert abs(z[hil.Z_GPS_POS + 2] - gps_pos[2]) <= HALF_MM
        assert np.abs(z[hil.Z_GPS_VEL : hil.Z_GPS_VEL + 3] - gps_vel).max() <= HALF_CM
        # the truth: the 12 VehicleState fields, then the body rates
        assert np.abs(truth[0:2] - s[0:2]).max() <= HALF_LATLON_M and abs(truth[2] - s[2]) <= HALF_MM
        assert np.abs(truth[3:6] - s[3:6]).max() <= HALF_CM
        assert np.abs(truth[6:9] - s[6:9]).max() <= 2e-6  # angles through a float32 quaternion
        assert np.abs(truth[9:12] - s[9:12]).max() <= 2e-5  # Euler-angle rates through float32 body rates
        pqr = frames.euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11])
        assert list(truth[12:15]) == [f32(v) for v in pqr]


def test_only_what_fields_updated_says_is_new():
    buf = new_buf()
    truth, frame = np.zeros(hil.TRUTH_DECODED), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    for fields in range(2**13):
        n = sensor_frame(buf, fields=fields)
        z = np.zeros(hil.Z_SIZE)
        t, flags, dropped = hil.decode_sensors(buf, n, PX4_HOME, z, truth, frame)
        expected = (
            (hil.MAG_NEW if fields & 0b111000000 == 0b111000000 else 0)
            | (hil.BARO_NEW if fields & hil.BARO_UPDATED == hil.BARO_UPDATED else 0)
            | (hil.IMU_NEW if fields & 0b111111 == 0b111111 else 0)
        )  # accel and gyro both, or no IMU sample
        assert (t, flags, dropped) == (1000, expected, 0), bin(fields)
        if not flags & hil.IMU_NEW:  # none: z keeps the last (zeros here)
            assert not z[hil.Z_GYRO : hil.Z_ACCEL + 3].any()
    assert hil.BARO_UPDATED == 0b1101000000000 and hil.MAG_UPDATED == 0b111000000


def test_gps_is_new_only_when_a_hil_gps_frame_is_there():
    for gps in (False, True):
        z = np.full(hil.Z_SIZE, 7.0)
        _, flags, _, z, _ = decode(datagram(gps=gps)[0], z)
        assert bool(flags & hil.GPS_NEW) == gps
        assert (z[hil.Z_GPS_POS : hil.Z_GPS_VEL + 3] == 7.0).all() != gps


def test_a_datagram_without_the_truth_leaves_it_nan():
    for gps in (False, True):
        truth = np.zeros(hil.TRUTH_DECODED)
        d, _ = datagram(gps=gps, truth=False)
        t = hil.decode_sensors(d, len(d), PX4_HOME, np.zeros(hil.Z_SIZE), truth, np.zeros(codec.FRAME_MAX, np.uint8))[0]
        assert t == 1000 and np.isnan(truth).all()


def test_a_corrupt_payload_byte_in_any_frame_is_a_bad_crc():
    d, bounds = datagram()
    assert len(bounds) == 3
    for start, end in bounds:
        for at in range(start + codec.HEADER_SIZE, end):  # every payload byte and the CRC itself
            for flip in (0x01, 0x80):
                bad = d.copy()
                bad[at] ^= flip
                assert decode(bad)[0] == codec.BAD_CRC, (start, at)


def test_an_unrelated_message_in_the_datagram_is_not_this_frame():
    d, bounds = datagram()
    heartbeat = as_array(packed(M.MAVLink_heartbeat_message(2, 12, 0, 0, 0, 3), 0))
    for at in (0, bounds[0][1], bounds[1][1], len(d)):
        assert decode(np.concatenate([d[:at], heartbeat, d[at:]]))[0] == codec.NOT_THIS_FRAME, at


def test_a_datagram_without_hil_sensor_is_not_this_frame():
    buf = new_buf()
    n = hil.encode_gps(buf, 0, SYS, COMP, 5, (1.0, 2.0, 3.0), (1.0, 0.0, 0.0), PX4_HOME, 1.0, 1.0, 10)
    assert decode(buf[:n].copy())[0] == codec.NOT_THIS_FRAME
    n += hil.encode_truth(buf[n:], 1, SYS, COMP, 5, STATE, 1.0, (0.0, 0.0, -9.8), PX4_HOME)
    assert decode(buf[:n].copy())[0] == codec.NOT_THIS_FRAME
    assert decode(np.zeros(0, np.uint8))[0] == codec.NOT_THIS_FRAME


def test_a_truncated_datagram_is_not_this_frame():
    d, bounds = datagram()
    ends = {end for _, end in bounds}
    for cut in range(1, len(d)):
        if cut not in ends:
            assert decode(d[:cut].copy())[0] == codec.NOT_THIS_FRAME, cut
    assert decode(d[: bounds[0][1]].copy())[0] == 1000  # cut at a frame's end: a shorter datagram, still good


def test_a_signed_frame_is_not_this_frame():
    d, bounds = datagram()
    for start, _ in bounds:
        signed = d.copy()
        signed[start + 2] = 1  # incompat flags: MAVLINK_IFLAG_SIGNED
        assert decode(signed)[0] == codec.NOT_THIS_FRAME, start
    mav = wire.link(SYS, COMP)
    wire.enable_signing(mav, bytes(range(32)))
    ref = M.MAVLink_hil_sensor_message(1000, 0.1, -0.2, -9.8, 0.0, 0.0, 0.0, 0.2, 0.0, 0.4, 955.0, 0.0, 488.0, 12.0,
                                       ALL_FIELDS, 0)  # fmt: skip
    frame = as_array(ref.pack(mav))
    assert frame[2] == 1 and len(frame) == codec.HEADER_SIZE + frame[1] + 2 + 13  # really signed
    assert decode(frame)[0] == codec.NOT_THIS_FRAME


# ---- non-finite samples and fixes without 3D --------------------------------------------------------------------


@pytest.mark.parametrize("bad", [{"accel": (math.nan, 0.0, -9.8)}, {"gyro": (0.0, math.inf, 0.0)},
                                 {"accel": (0.0, 0.0, -math.inf)}])  # fmt: skip
def test_a_non_finite_imu_sample_is_dropped_and_the_previous_one_kept(bad):
    z = np.full(hil.Z_SIZE, 7.0)
    t, flags, dropped, z, _ = decode(datagram(gps=False, **bad)[0], z)
    assert t == 1000 and dropped == hil.IMU_DROPPED
    assert (z[hil.Z_ACCEL : hil.Z_ACCEL + 3] == 7.0).all() and (z[hil.Z_GYRO : hil.Z_GYRO + 3] == 7.0).all()
    assert flags == hil.MAG_NEW | hil.BARO_NEW  # the other sensors' samples are still used
    assert z[hil.Z_BARO] == np.float32(488.3)


def test_a_non_finite_magnetometer_sample_is_dropped():
    z = np.full(hil.Z_SIZE, 7.0)
    t, flags, dropped, z, _ = decode(datagram(gps=False, mag=(0.2, math.nan, 0.4))[0], z)
    assert t == 1000 and dropped == hil.MAG_DROPPED and flags == hil.IMU_NEW | hil.BARO_NEW
    assert (z[hil.Z_MAG : hil.Z_MAG + 3] == 7.0).all()
    assert z[hil.Z_ACCEL + 2] == np.float32(-9.8)  # the IMU's sample is still used
    no_mag = ALL_FIELDS & ~hil.MAG_UPDATED  # a NaN in a field not marked updated is not looked at
    _, flags, dropped, _, _ = decode(datagram(gps=False, mag=(math.nan,) * 3, fields=no_mag)[0])
    assert (flags, dropped) == (hil.IMU_NEW | hil.BARO_NEW, 0)


def test_a_non_finite_pressure_altitude_is_dropped():
    for alt in (math.inf, -math.inf, math.nan):
        z = np.full(hil.Z_SIZE, 7.0)
        t, flags, dropped, z, _ = decode(datagram(gps=False, baro=(955.0, alt, 11.0))[0], z)
        assert t == 1000 and dropped == hil.BARO_DROPPED and flags == hil.IMU_NEW | hil.MAG_NEW
        assert z[hil.Z_BARO] == 7.0


def hil_gps_frame(fix_type, lat=473977420, seq=1) -> np.ndarray:
    m = M.MAVLink_hil_gps_message(880, fix_type, lat, 85455940, 491200, 100, 200, 133, 123, -50, 20, 3390, 10)
    return as_array(packed(m, seq))


def test_a_gps_without_a_3d_fix_is_ignored():
    d, _ = datagram(gps=False, truth=False)
    z = np.full(hil.Z_SIZE, 7.0)
    _, flags, dropped, z, _ = decode(np.concatenate([d, hil_gps_frame(3)]), z)  # the same frame with a 3D fix is used
    assert flags & hil.GPS_NEW and dropped == 0
    assert np.allclose(z[hil.Z_GPS_POS : hil.Z_GPS_POS + 3], (0.0, 0.0, -3.2), rtol=0, atol=HALF_LATLON_M)
    assert np.allclose(z[hil.Z_GPS_VEL : hil.Z_GPS_VEL + 3], (1.23, -0.5, 0.2), rtol=0, atol=1e-12)
    for fix_type in (0, 1, 2):
        z = np.full(hil.Z_SIZE, 7.0)
        t, flags, dropped, z, _ = decode(np.concatenate([d, hil_gps_frame(fix_type)]), z)
        assert t == 1000 and flags & hil.GPS_NEW == 0 and dropped == 0
        assert (z[hil.Z_GPS_POS : hil.Z_GPS_VEL + 3] == 7.0).all()


def test_a_gps_off_the_globe_is_dropped():
    d, _ = datagram(gps=False, truth=False)
    z = np.full(hil.Z_SIZE, 7.0)
    _, flags, dropped, z, _ = decode(np.concatenate([d, hil_gps_frame(3, lat=910000000)]), z)
    assert flags & hil.GPS_NEW == 0 and dropped == hil.GPS_DROPPED
    assert (z[hil.Z_GPS_POS : hil.Z_GPS_VEL + 3] == 7.0).all()


# ---- sizes --------------------------------------------------------------------------------------------------------


def test_datagram_max_holds_the_largest_tick():
    # every field non-zero up to the last, so MAVLink 2 trims nothing but the always-zero ids/yaw
    d, bounds = datagram(fields=0xFFFFFFFF, t=2**40, state=(*STATE[:-1], 0.5))
    assert len(bounds) == 3 and len(d) <= hil.DATAGRAM_MAX
    full = sum(codec.HEADER_SIZE + size + 2 for size in (hil.SENSOR_SIZE, hil.GPS_SIZE, hil.TRUTH_SIZE))
    assert full <= hil.DATAGRAM_MAX  # untrimmed frames, as the encoders write them before trimming
