"""The simulated sensors (sitl.sensors): noise as its density and Gauss–Markov parameters say, the ISA barometer,
the Earth's field, the GPS's rate and delay and its units on the wire, determinism by seed, and the [sensors]
preset section."""

import dataclasses
import math

import numpy as np
import pytest

from quadsitl import earth, frames
from quadsitl.config import IMU_PROFILES, ConfigError, SensorParams, parse_preset
from quadsitl.frames import body_to_ned, euler_to_quaternion, ned_to_body
from quadsitl.wire import gps_from_message, hil_gps_message, link
from sitl.sensors import (
    ACCEL_UPDATED,
    BARO_UPDATED,
    GYRO_UPDATED,
    MAG_UPDATED,
    OUT_ACCEL,
    OUT_GPS_POS,
    OUT_GPS_TIME,
    OUT_GPS_VEL,
    OUT_GYRO,
    OUT_MAG,
    OUT_PRESSURE,
    OUT_PRESSURE_ALT,
    OUT_TEMPERATURE,
    Sensors,
)

G = 9.80665
T = 0.001  # control period [s]
LEVEL = (0.0,) * 12
QUIET_GPS = {"gps_xy_error_m": 0.0, "gps_z_error_m": 0.0, "gps_xy_velocity_noise_m_s": 0.0,
             "gps_z_velocity_noise_m_s": 0.0}  # fmt: skip
X500 = (__import__("importlib").resources.files("quadsitl") / "presets" / "x500.toml").read_text()


def record(sensors: Sensors, n: int, state=LEVEL, accel=(0.0, 0.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """n ticks of a vehicle held at ``state``: (outputs (n, OUT_SIZE), fields_updated (n,))."""
    out = np.empty((n, sensors.out.size))
    fields = np.empty(n, dtype=np.int64)
    for k in range(n):
        fields[k] = sensors.tick(k * 1000, state, accel)
        out[k] = sensors.out
    return out, fields


def params(**kw) -> SensorParams:
    return dataclasses.replace(SensorParams(), **kw)


@pytest.mark.timeout(60)
def test_static_imu_white_noise_matches_its_density_over_100_s():
    """PX4 profile (no bias): over 100 simulated seconds at 1 kHz, each axis's standard deviation is the noise
    density / √dt within 5 %, around the true specific force (0, 0, −g) and zero rates."""
    s = SensorParams()
    out, fields = record(Sensors(s, T, G), 100_000)
    assert (fields & (ACCEL_UPDATED | GYRO_UPDATED) == ACCEL_UPDATED | GYRO_UPDATED).all()
    for at, density, truth in ((OUT_ACCEL, s.accel_noise_density_m_s2_sqrt_hz, (0.0, 0.0, -G)),
                               (OUT_GYRO, s.gyro_noise_density_rad_s_sqrt_hz, (0.0, 0.0, 0.0))):  # fmt: skip
        sigma = density / math.sqrt(T)
        x = out[:, at : at + 3]
        assert np.abs(x.std(axis=0) / sigma - 1.0).max() < 0.05
        assert np.abs(x.mean(axis=0) - truth).max() < 4 * sigma / math.sqrt(len(x))
        lag1 = [np.corrcoef(x[:-1, i], x[1:, i])[0, 1] for i in range(3)]
        assert max(abs(c) for c in lag1) < 0.02  # white


@pytest.mark.timeout(60)
def test_adis16448_profile_white_noise_and_turn_on_bias():
    """The ADIS16448 profile: the white part (from differences of successive samples, which cancel the slow bias)
    has its density's σ, and over 100 seeds × 3 axes the turn-on biases have the σ the profile gives."""
    p = dataclasses.replace(SensorParams(), profile="adis16448", **IMU_PROFILES["adis16448"])
    out, _ = record(Sensors(p, T, G), 20_000)
    for at, density in (
        (OUT_GYRO, p.gyro_noise_density_rad_s_sqrt_hz),
        (OUT_ACCEL, p.accel_noise_density_m_s2_sqrt_hz),
    ):
        white = np.diff(out[:, at : at + 3], axis=0).std(axis=0) / math.sqrt(2)
        assert np.abs(white / (density / math.sqrt(T)) - 1.0).max() < 0.05
    gyro_bias, accel_bias = [], []
    for seed in range(100):
        sensors = Sensors(dataclasses.replace(p, seed=seed), T, G)
        gyro_bias += list(sensors.bias[0:3])
        accel_bias += list(sensors.bias[3:6])
    # 300 samples: the standard deviation's standard error is 4 %; allow 3 of them
    assert np.std(gyro_bias) == pytest.approx(p.gyro_turn_on_bias_rad_s, rel=0.12)
    assert np.std(accel_bias) == pytest.approx(p.accel_turn_on_bias_m_s2, rel=0.12)


@pytest.mark.timeout(60)
def test_bias_is_the_gauss_markov_process_its_parameters_say():
    """Gyro bias alone (no white noise, no turn-on bias): with τ = 0.05 s its stationary σ is RW·√(τ/2) and its
    autocorrelation at lag τ is e^-1; with the ADIS figures (τ = 1000 s) it grows from zero as a random walk,
    variance RW²·t, over 200 runs."""
    rw, tau = 0.02, 0.05
    p = params(
        gyro_noise_density_rad_s_sqrt_hz=0.0, gyro_random_walk_rad_s2_sqrt_hz=rw, gyro_bias_correlation_time_s=tau
    )
    out, _ = record(Sensors(p, T, G), 100_000)
    b = out[1000:, OUT_GYRO : OUT_GYRO + 3]  # after 20 τ: stationary
    assert np.abs(b.std(axis=0) / (rw * math.sqrt(tau / 2)) - 1.0).max() < 0.05
    lag = round(tau / T)
    rho = [np.corrcoef(b[:-lag, i], b[lag:, i])[0, 1] for i in range(3)]
    assert np.abs(np.array(rho) - math.exp(-1)).max() < 0.04
    rw = IMU_PROFILES["adis16448"]["gyro_random_walk_rad_s2_sqrt_hz"]
    finals = []
    for seed in range(200):
        p = params(seed=seed, gyro_noise_density_rad_s_sqrt_hz=0.0, gyro_random_walk_rad_s2_sqrt_hz=rw)
        out, _ = record(Sensors(p, T, G), 1000)
        finals += list(out[-1, OUT_GYRO : OUT_GYRO + 3])
    # 600 samples: the variance's standard error is 6 %; allow 3 of them
    assert np.var(finals) == pytest.approx(rw**2 * 1.0, rel=0.18)


def test_isa_barometer_matches_the_standard_atmosphere():
    assert earth.isa_pressure(0.0) == pytest.approx(101325.0, abs=1e-9)
    assert earth.isa_pressure(1000.0) / 100 == pytest.approx(898.76, abs=0.02)  # ISA table, hPa
    assert earth.isa_pressure(11000.0) / 100 == pytest.approx(226.32, abs=0.1)
    assert earth.isa_temperature(1000.0) == pytest.approx(281.65, abs=1e-9)
    assert earth.isa_density(0.0) == pytest.approx(1.225, abs=1e-3)
    for h in (-100.0, 0.0, 488.0, 3000.0, 10000.0):
        assert earth.isa_altitude(earth.isa_pressure(h)) == pytest.approx(h, abs=1e-6)


def test_barometer_at_home_and_50_hz_and_mag_at_100_hz():
    """At rest on the ground at home (488 m AMSL): pressure, pressure altitude and temperature of the ISA there,
    1 Pa of noise; a baro sample every 20 ticks and a magnetometer sample every 10."""
    s = SensorParams()
    out, fields = record(Sensors(s, T, G), 20_000)
    baro = (fields & BARO_UPDATED) == BARO_UPDATED
    mag = (fields & MAG_UPDATED) == MAG_UPDATED
    assert np.flatnonzero(baro).tolist() == list(range(0, 20_000, 20))
    assert np.flatnonzero(mag).tolist() == list(range(0, 20_000, 10))
    pressure = out[baro, OUT_PRESSURE] * 100  # Pa
    assert pressure.mean() == pytest.approx(earth.isa_pressure(488.0), abs=4 * 1.0 / math.sqrt(len(pressure)))
    assert pressure.std() == pytest.approx(s.baro_noise_pa, rel=0.1)  # 1000 samples
    # 1 Pa is about 8.7 cm at 488 m: dp/dh = −ρ·g
    alt_sigma = s.baro_noise_pa / (earth.isa_density(488.0) * earth.G0)
    assert out[baro, OUT_PRESSURE_ALT].std() == pytest.approx(alt_sigma, rel=0.1)
    assert out[baro, OUT_PRESSURE_ALT].mean() == pytest.approx(488.0, abs=0.02)
    assert out[baro, OUT_TEMPERATURE] == pytest.approx(15.0 - 0.0065 * 488.0)
    climbed, _ = record(Sensors(s, T, G), 1, state=(0.0, 0.0, -1000.0, *LEVEL[3:]))
    assert climbed[0, OUT_PRESSURE_ALT] == pytest.approx(1488.0, abs=0.5)


def test_magnetometer_measures_the_earth_field_at_home():
    """Level and heading north, the mean field has the configured intensity, inclination and declination; turned
    to heading 90°, the body axes see it turned back by 90°."""
    s = SensorParams()
    out, fields = record(Sensors(s, T, G), 10_000)
    m = out[(fields & MAG_UPDATED) != 0, OUT_MAG : OUT_MAG + 3].mean(axis=0)
    assert np.linalg.norm(m) == pytest.approx(s.mag_strength_gauss, rel=2e-3)
    assert math.degrees(math.atan2(m[2], math.hypot(m[0], m[1]))) == pytest.approx(s.mag_inclination_deg, abs=0.2)
    assert math.degrees(math.atan2(m[1], m[0])) == pytest.approx(s.mag_declination_deg, abs=0.3)
    east = (0.0,) * 8 + (math.pi / 2, 0.0, 0.0, 0.0)
    out, fields = record(Sensors(s, T, G), 10_000, state=east)
    m = out[(fields & MAG_UPDATED) != 0, OUT_MAG : OUT_MAG + 3].mean(axis=0)
    assert math.degrees(math.atan2(m[1], m[0])) == pytest.approx(s.mag_declination_deg - 90.0, abs=0.3)


def test_accelerometer_measures_specific_force_in_body_axes():
    """Rolled 30° and hovering (a = 0): the accelerometer reads −g along the tilted body "up"; accelerating
    north at 2 m/s² level: +2 on the forward axis (noise-free sensors)."""
    quiet = params(gyro_noise_density_rad_s_sqrt_hz=0.0, accel_noise_density_m_s2_sqrt_hz=0.0)
    roll = math.radians(30)
    out, _ = record(Sensors(quiet, T, G), 1, state=(0.0,) * 6 + (roll, 0.0, 0.0, 0.5, 0.0, 0.0))
    assert out[0, OUT_ACCEL : OUT_ACCEL + 3] == pytest.approx((0.0, -G * math.sin(roll), -G * math.cos(roll)))
    assert out[0, OUT_GYRO : OUT_GYRO + 3] == pytest.approx((0.5, 0.0, 0.0))
    out, _ = record(Sensors(quiet, T, G), 1, accel=(2.0, 0.0, 0.0))
    assert out[0, OUT_ACCEL : OUT_ACCEL + 3] == pytest.approx((2.0, 0.0, -G))


def test_frames_rotate_vectors_as_the_horizontal_equations_say():
    """body_to_ned is R(q) of euler_to_quaternion: thrust along −z_body gives DESIGN.md §2's horizontal terms."""
    roll, pitch, yaw = 0.3, -0.2, 2.0
    q = euler_to_quaternion(roll, pitch, yaw)
    n, e, d = body_to_ned(q, 0.0, 0.0, -1.0)
    cf, sf, ct, st, cp, sp = (math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw),
                              math.sin(yaw))  # fmt: skip
    assert (n, e, d) == pytest.approx((-(cf * st * cp + sf * sp), -(cf * st * sp - sf * cp), -cf * ct))
    assert ned_to_body(q, n, e, d) == pytest.approx((0.0, 0.0, -1.0))
    assert body_to_ned(euler_to_quaternion(0.0, 0.0, math.pi / 2), 1.0, 0.0, 0.0) == pytest.approx((0.0, 1.0, 0.0))


def test_gps_at_10_hz_delayed_by_exactly_120_ms():
    """A vehicle flying north at 5 m/s: fixes arrive every 100 ms from t = 120 ms, each one the position 120 ms
    before its arrival (noise-free GPS)."""
    s = params(**QUIET_GPS)
    sensors = Sensors(s, T, G)
    arrivals = []
    for k in range(2000):
        t = k * T
        sensors.tick(k * 1000, (5.0 * t, 0.0, -2.0, 5.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
        if sensors.gps_new:
            arrivals.append(
                (k, sensors.out[OUT_GPS_TIME], sensors.out[OUT_GPS_POS], *sensors.out[OUT_GPS_VEL : OUT_GPS_VEL + 3])
            )
    ticks = [a[0] for a in arrivals]
    assert ticks == list(range(120, 2000, 100))
    for k, measured_us, north, vn, _, _ in arrivals:
        assert measured_us == (k - 120) * 1000
        assert north == pytest.approx(5.0 * (k - 120) * T, abs=1e-12)
        assert vn == 5.0


def test_gps_on_the_wire_in_px4_units():
    """HIL_GPS: lat/lon in 1e-7 deg, altitude AMSL in mm, velocities in cm/s, eph/epv in cm, 3D fix; decoded by
    pymavlink and turned back into the local position within the encoding's resolution."""
    home = (frames.HOME_LAT, frames.HOME_LON, frames.HOME_ALT)
    msg = hil_gps_message(120_000, (100.0, -50.0, -20.0), (3.0, -4.0, 0.5), home, 1.0, 2.0, 10)
    mav = link(1, 1)
    m = mav.parse_buffer(msg.pack(mav))[0]
    assert m.get_type() == "HIL_GPS" and m.fix_type == 3 and m.satellites_visible == 10
    assert (m.vn, m.ve, m.vd, m.vel, m.eph, m.epv) == (300, -400, 50, 500, 100, 200)
    assert m.alt == 508_000 and m.cog == round((math.degrees(math.atan2(-4, 3)) % 360) * 100)
    assert m.lat == pytest.approx((frames.HOME_LAT + 100.0 / 6371000.0 * 180 / math.pi) * 1e7, abs=1)
    position, velocity = gps_from_message(m, home)
    assert position == pytest.approx((100.0, -50.0, -20.0), abs=0.012)  # 1e-7 deg ≈ 1.1 cm
    assert velocity == pytest.approx((3.0, -4.0, 0.5))


def test_gps_error_wanders_slowly_with_its_sigma():
    """The position error is a Gauss–Markov process: σ as configured, strongly correlated over a second."""
    s = params(gps_error_correlation_time_s=5.0)
    sensors = Sensors(s, T, G)
    errors = []
    for k in range(200_000):
        sensors.tick(k * 1000, LEVEL, (0.0, 0.0, 0.0))
        if sensors.gps_new:
            errors.append(sensors.out[OUT_GPS_POS : OUT_GPS_POS + 3].copy())
    e = np.array(errors)  # 2000 fixes over 40 correlation times
    assert e[:, :2].std() == pytest.approx(s.gps_xy_error_m, rel=0.2)
    assert np.corrcoef(e[:-10, 0], e[10:, 0])[0, 1] == pytest.approx(math.exp(-1 / 5.0), abs=0.1)


def test_same_seed_same_samples_other_seed_other_samples():
    a, _ = record(Sensors(SensorParams(), T, G), 3000, accel=(0.1, 0.2, 0.3))
    b, _ = record(Sensors(SensorParams(), T, G), 3000, accel=(0.1, 0.2, 0.3))
    c, _ = record(Sensors(params(seed=1), T, G), 3000, accel=(0.1, 0.2, 0.3))
    assert a.tobytes() == b.tobytes()
    assert not np.isclose(a[:, OUT_GYRO], c[:, OUT_GYRO]).any()


# ---- the [sensors] preset section --------------------------------------------------------------------------


def test_presets_without_the_section_fly_on_the_truth():
    assert parse_preset(X500, "x").sensors is None


def test_sensors_section_defaults_profile_and_overrides():
    p = parse_preset(X500 + "\n[sensors]\n", "x").sensors
    assert p == SensorParams()
    p = parse_preset(
        X500 + '\n[sensors]\nprofile = "adis16448"\naccel_turn_on_bias_m_s2 = 0.1\nseed = 7\n', "x"
    ).sensors
    assert p.gyro_noise_density_rad_s_sqrt_hz == 3.394e-4 and p.gyro_turn_on_bias_rad_s == 0.0087
    assert p.accel_turn_on_bias_m_s2 == 0.1 and p.seed == 7 and p.profile == "adis16448"


@pytest.mark.parametrize(
    ("lines", "message"),
    [
        ('profile = "mpu6000"', r"sensors\.profile = 'mpu6000': expected one of: px4, adis16448"),
        ("gyro_noise_density_rad_s_sqrt_hz = -1e-4", r"sensors\.gyro_noise_density_rad_s_sqrt_hz = -0\.0001: expected"),
        ("accel_bias_correlation_time_s = 0", r"sensors\.accel_bias_correlation_time_s = 0: expected a number in \(0"),
        ("seed = -1", r"sensors\.seed = -1: expected an integer"),
        ("seed = 1.5", r"sensors\.seed = 1\.5: expected an integer"),
        ("baro_noise_pa = nan", r"sensors\.baro_noise_pa = nan"),
        ("mag_inclination_deg = 95", r"sensors\.mag_inclination_deg = 95: expected a number in \[-90, 90\] deg"),
        ("gps_rate_hz = 5000", r"sensors\.gps_rate_hz = 5000: expected a number in \[1, 100\] Hz"),
        ("gyro_noise = 0.1", r"unknown key sensors\.gyro_noise; allowed in \[sensors\]: profile, seed"),
    ],
)
def test_bad_sensor_values_are_refused_with_key_value_and_range(lines, message):
    with pytest.raises(ConfigError, match=message):
        parse_preset(X500 + "\n[sensors]\n" + lines + "\n", "x")


def test_inconsistent_sensor_values_are_refused():
    slow = X500.replace("period = 0.001", "period = 0.02")  # a 50 Hz control loop
    with pytest.raises(ConfigError, match=r"sensors\.mag_rate_hz = 100\.0: must not exceed the control rate .* 50 Hz"):
        parse_preset(slow + "\n[sensors]\n", "x")
    assert parse_preset(slow + "\n[sensors]\nmag_rate_hz = 50\n", "x").sensors.mag_rate_hz == 50.0
    with pytest.raises(ConfigError, match=r"sensors\.gps_delay_s = 0\.9: with sensors\.gps_rate_hz = 50\.0"):
        parse_preset(X500 + "\n[sensors]\ngps_rate_hz = 50\ngps_delay_s = 0.9\n", "x")


_SAMPLES = """
import sys
import numpy as np
from quadsitl.config import SensorParams
from sitl.sensors import Sensors
s = Sensors(SensorParams(seed=5, gyro_turn_on_bias_rad_s=0.01, accel_random_walk_m_s3_sqrt_hz=0.01), 0.001, 9.80665)
out = []
for k in range(1500):
    s.tick(k * 1000, (1.0, 2.0, -3.0, 0.5, -0.5, 0.1, 0.2, -0.1, 1.0, 0.3, 0.2, 0.1), (0.1, 0.2, 0.3))
    out.append(s.out.copy())
sys.stdout.write(np.array(out).tobytes().hex())
"""


@pytest.mark.timeout(60)
def test_compiled_and_plain_python_give_the_same_samples_bit_for_bit():
    """The same source under NUMBA_DISABLE_JIT=1: the same random streams, the same samples, to the bit."""
    from tests.both_runtimes import outputs

    compiled, plain = outputs(_SAMPLES)
    assert len(compiled) == 1500 * 20 * 16 and compiled == plain


def test_a_box_muller_pair_is_two_independent_standard_normals():
    """normal_pair: both deviates of a Box–Muller pair (the first is normal's from the same state), each standard
    normal, and uncorrelated, over 200,000 pairs."""
    from sitl.noise import normal, normal_pair, seed_streams

    s = seed_streams(7, 1)
    first = normal(s.copy(), 0)
    assert normal_pair(s.copy(), 0)[0] == first
    pairs = np.array([normal_pair(s, 0) for _ in range(200_000)])
    assert np.abs(pairs.mean(axis=0)).max() < 0.01  # σ/√n = 0.0022
    assert np.abs(pairs.std(axis=0) - 1.0).max() < 0.01
    assert abs(np.corrcoef(pairs.T)[0, 1]) < 0.01
    # the tails of a normal: |x| > 3 for 0.27 % of samples
    assert 0.0022 < np.mean(np.abs(pairs) > 3.0) < 0.0032
