"""The wind model (sitl/wind.py) alone: the mean wind's direction, the 1 − cos gust, and the Dryden turbulence's
intensity, correlation and spectrum against MIL-F-8785C, seeded and the same compiled or not."""

import copy
import math

import numpy as np
import pytest

from quadsitl.config import WindParams
from sitl.wind import KNOT, dryden_scales, gamma_lower, gust, wind_params, wind_state, wind_step
from tests.both_runtimes import outputs


def fly(wind: WindParams, steps: int, dt: float, altitude: float, airspeed: float) -> np.ndarray:
    """The wind [m/s, NED] at each of ``steps`` steps."""
    p = wind_params(wind)
    x, rng = wind_state(wind.seed)
    out, rec = np.zeros(3), np.zeros((steps, 3))
    for k in range(steps):
        wind_step(out, x, rng, p, k * dt, dt, altitude, airspeed)
        rec[k] = out
    return rec


def test_the_mean_wind_blows_from_where_it_is_said_to():
    for from_deg, north, east in (
        (270.0, 0.0, 5.0),
        (0.0, -5.0, 0.0),
        (90.0, 0.0, -5.0),
        (225.0, 5 / 2**0.5, 5 / 2**0.5),
    ):
        w = fly(WindParams(speed_m_s=5.0, from_deg=from_deg), 3, 0.001, 10.0, 5.0)
        assert w[-1] == pytest.approx([north, east, 0.0], abs=1e-12), from_deg
    assert not fly(WindParams(), 100, 0.001, 10.0, 0.0).any()  # no wind, no turbulence: exactly calm


def test_the_gust_is_one_minus_cosine_then_holds():
    p = wind_params(WindParams(gust_m_s=4.0, gust_rise_s=2.0, gust_start_s=1.0, gust_from_deg=180.0))
    for t, want in (
        (0.0, 0.0),
        (1.0, 0.0),
        (1.5, 2.0 * (1 - math.cos(math.pi / 4))),
        (2.0, 2.0),
        (3.0, 4.0),
        (9.0, 4.0),
    ):
        assert gust(p, t) == pytest.approx(want, abs=1e-12), t
    out, (x, rng) = np.zeros(3), wind_state(0)
    wind_step(out, x, rng, p, 5.0, 0.001, 10.0, 0.0)
    assert out == pytest.approx([4.0, 0.0, 0.0], abs=1e-12)  # from the south: the air moves north


def test_the_incomplete_gamma_function_by_series_and_closed_form():
    for n in (1, 2, 3):
        for x in (1e-6, 1e-3, 0.3, 0.999, 1.0, 2.5, 40.0):  # the series below 1, the closed form above
            t = np.linspace(0.0, x, 200001)
            f = t ** (n - 1) * np.exp(-t)
            want = float(np.sum((f[1:] + f[:-1]) / 2 * np.diff(t)))
            assert gamma_lower(n, x) == pytest.approx(want, rel=1e-8), (n, x)


def test_the_series_stops_where_its_terms_no_longer_change_the_sum():
    """The series ends once a term is below half an ulp of the sum: the result is the whole 30-term series's, to the
    bit (as plain Python, where both are the same arithmetic), for arguments across [0, 1)."""

    def whole(n: int, x: float) -> float:
        total, term, k = 0.0, 1.0, 0
        while k < 30:
            total += term / (k + n)
            k += 1
            term *= -x / k
        return x**n * total

    rng = np.random.default_rng(45)
    for x in np.concatenate([rng.uniform(0.0, 1.0, 3000), 10.0 ** rng.uniform(-12.0, 0.0, 3000)]).tolist():
        for n in (1, 2, 3):
            assert gamma_lower.py_func(n, x) == whole(n, x), (n, x)


# A long record at 50 m/s and 20 m: L_u = L_v = 116 m, L_w = 20 m, so τ_u = 2.3 s and τ_w = 0.4 s. The steps
# are exact at any size: 20,000 s in 0.05 s steps is ~4,000 independent stretches of u, so a standard deviation
# is known to ~1 % and an autocorrelation to ~0.016 (the bounds below are three times that or more).
V, H, DT, STEPS = 50.0, 20.0, 0.05, 400_000
MODERATE = WindParams(speed_m_s=V, from_deg=270.0, turbulence="moderate", seed=3)


def turbulence() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """u (along the wind: east), v (its right: south), w (down) of a long moderate record at airspeed V."""
    w = fly(MODERATE, STEPS, DT, H, V)[400:]  # from 20 s (~9 τ_u): the filters start calm
    return w[:, 1] - V, -w[:, 0], w[:, 2]


@pytest.fixture(scope="module")
def uvw():
    return turbulence()


def test_dryden_intensities_and_lengths_are_mil_f_8785c():
    s_uv, s_w, l_uv, l_w = dryden_scales(H, 30 * KNOT)
    h_ft = H / 0.3048
    assert s_w == pytest.approx(0.1 * 30 * KNOT) and l_w == pytest.approx(H)
    assert s_uv == pytest.approx(s_w / (0.177 + 0.000823 * h_ft) ** 0.4)
    assert l_uv == pytest.approx(h_ft / (0.177 + 0.000823 * h_ft) ** 1.2 * 0.3048)
    assert dryden_scales(0.0, 1.0) == dryden_scales(10 * 0.3048, 1.0)  # held at 10 ft near the ground
    assert dryden_scales(1e4, 1.0) == dryden_scales(1000 * 0.3048, 1.0)


def test_dryden_standard_deviations_match_their_intensities(uvw):
    s_uv, s_w, _, _ = dryden_scales(H, 30 * KNOT)
    for series, sigma in zip(uvw, (s_uv, s_uv, s_w), strict=True):
        assert abs(series.mean()) < 0.1 * sigma
        assert series.std() == pytest.approx(sigma, rel=0.04)


def test_dryden_autocorrelations_are_the_models(uvw):
    """u: e^(−ξ/L); v, w: (1 − ξ/(2L))·e^(−ξ/L), ξ = V·lag (MIL-F-8785C's correlation functions)."""
    _, _, l_uv, l_w = dryden_scales(H, 30 * KNOT)
    for series, length, second in ((uvw[0], l_uv, False), (uvw[1], l_uv, True), (uvw[2], l_w, True)):
        s = series - series.mean()
        for lag_l in (0.5, 1.0, 2.0):
            lag = round(lag_l * length / V / DT)
            r = np.dot(s[:-lag], s[lag:]) / np.dot(s, s)
            xi = lag * DT * V / length
            want = (1 - xi / 2) * math.exp(-xi) if second else math.exp(-xi)
            assert r == pytest.approx(want, abs=0.05), (length, lag_l, r, want)


def test_dryden_vertical_spectrum_is_its_transfer_function(uvw):
    """The share of w's variance in bands of ω·L/V, measured (averaged periodograms) against |H_w(jω)|²."""
    _, _, _, l_w = dryden_scales(H, 30 * KNOT)
    tau = l_w / V
    seg = 8192
    w = uvw[2][: len(uvw[2]) // seg * seg].reshape(-1, seg)
    w = w - w.mean(axis=1, keepdims=True)
    power = (np.abs(np.fft.rfft(w * np.hanning(seg), axis=1)) ** 2).mean(axis=0)
    omega = 2 * np.pi * np.fft.rfftfreq(seg, DT)
    model = (1 + 3 * (tau * omega) ** 2) / (1 + (tau * omega) ** 2) ** 2
    for lo, hi in ((0.1, 0.5), (0.5, 2.0), (2.0, 8.0)):
        band = (omega * tau >= lo) & (omega * tau < hi)
        share, want = power[band].sum() / power[1:].sum(), model[band].sum() / model[1:].sum()
        assert share == pytest.approx(want, rel=0.1), (lo, hi, share, want)


def test_seeds_repeat_to_the_bit_and_differ_from_each_other():
    a = fly(WindParams(turbulence="light", seed=7), 2000, 0.001, 5.0, 3.0)
    b = fly(WindParams(turbulence="light", seed=7), 2000, 0.001, 5.0, 3.0)
    c = fly(WindParams(turbulence="light", seed=8), 2000, 0.001, 5.0, 3.0)
    assert np.array_equal(a, b) and not np.array_equal(a, c)
    assert np.abs(a).max() > 0.0


WIND_SAMPLES = """
from tests.test_wind import fly
from tests.both_runtimes import outputs
from quadsitl.config import WindParams
w = fly(WindParams(speed_m_s=3.0, from_deg=45.0, turbulence="severe", gust_m_s=2.0, gust_start_s=0.1, seed=5),
        500, 0.001, 7.0, 4.0)
print(w.tobytes().hex())
"""


@pytest.mark.timeout(60)
def test_compiled_and_plain_python_give_the_same_wind_bit_for_bit():
    compiled, plain = outputs(WIND_SAMPLES)
    assert len(compiled) == 500 * 3 * 16 + 1 and compiled == plain


def test_a_change_while_flying_sets_the_wind_from_the_next_tick_and_a_gust_counts_from_the_change():
    import dataclasses

    from quadsitl.config import load_preset, wind_change
    from quadsitl.mixer import inputs_to_forces
    from sitl.plant import Plant
    from sitl.wind_link import change_wind

    paper = load_preset("paper")
    plant = Plant(dataclasses.replace(paper, initial=dataclasses.replace(paper.initial, altitude=10.0)))
    hover = inputs_to_forces((paper.vehicle.mass * paper.vehicle.gravity, 0, 0, 0), paper.vehicle.d_over_b)
    for _ in range(1000):  # 1 s of calm air in flight
        plant.step(hover)
    wind, since = change_wind(plant, WindParams(), wind_change('{"speed_m_s": 4, "from_deg": 90}'), 0.0)
    plant.step(hover)
    assert plant.wind == pytest.approx((0.0, -4.0, 0.0), abs=1e-12) and since == 0.0  # from the east: moving west
    # a gust of 2 m/s from the north 0.5 s after the change (at 1.001 s on the wind's clock), over 0.2 s
    wind, since = change_wind(plant, wind, wind_change('{"gust_m_s": 2, "gust_start_s": 0.5, "gust_rise_s": 0.2}'),
                              since)  # fmt: skip
    assert since == pytest.approx(1.001) and wind.speed_m_s == 4.0
    for _ in range(500):
        plant.step(hover)
    assert plant.wind == pytest.approx((0.0, -4.0, 0.0), abs=1e-12)  # not yet
    for _ in range(200):
        plant.step(hover)
    assert plant.wind[0] == pytest.approx(-2.0 * 0.5 * (1 - math.cos(math.pi * 0.199 / 0.2)), abs=1e-9)
    for _ in range(10):
        plant.step(hover)
    assert plant.wind == pytest.approx((-2.0, -4.0, 0.0), abs=1e-12)  # risen, and held
    # a new seed restarts the turbulence's stream: the same air as a plant that had that seed from the change on
    twin, other = copy.deepcopy(plant), copy.deepcopy(plant)
    twin.air_rng[:] = 0  # whatever its stream was, the seed restarts it
    for p, seed in ((plant, 5), (twin, 5), (other, 6)):
        change_wind(p, wind, wind_change(f'{{"turbulence": "light", "seed": {seed}}}'), since)
        for _ in range(100):
            p.step(hover)
    assert np.array_equal(plant.air, twin.air) and plant.wind[2] != 0.0 and plant.wind[2] != other.wind[2]
