"""SET_POSITION_TARGET_* and DO_REPOSITION as PX4 reads them (autopilot.setpoints): MAVSDK's masks, the frames,
and every refusal naming the field, the value and what is allowed."""

import math

import pytest

from autopilot.setpoints import Frame, SetpointError, position_target, reposition
from quadsitl.frames import ned_to_geodetic

ORIGIN = (47.397742, 8.545594, 488.0)
F = Frame(ORIGIN, home=(1.0, 2.0, 0.5), yaw=math.pi / 2)
NAN = math.nan


def target(mask, pos=(1.0, 2.0, -3.0), vel=(0.5, -0.5, -0.2), acc=(0.1, 0.2, 0.3), yaw=0.4, rate=0.1, frame=1, f=F):
    return position_target(frame, mask, pos, vel, acc, yaw, rate, f)


def same(a, b) -> bool:
    """Equal tuples, NaN equal to NaN (or both None)."""
    if a is None or b is None:
        return a is b
    return len(a) == len(b) and all(x == y or (math.isnan(x) and math.isnan(y)) for x, y in zip(a, b))


@pytest.mark.parametrize(
    "mask, horizontal, vertical, heading",
    [
        (2552, (1.0, 2.0, NAN, NAN, NAN, NAN), (3.0, NAN, NAN), (0.4, NAN)),  # position + yaw
        (2503, (NAN, NAN, 0.5, -0.5, NAN, NAN), (NAN, 0.2, NAN), (0.4, NAN)),  # velocity + yaw
        (2496, (1.0, 2.0, 0.5, -0.5, NAN, NAN), (3.0, 0.2, NAN), (0.4, NAN)),  # position + velocity (+ yaw)
        (2048, (1.0, 2.0, 0.5, -0.5, 0.1, 0.2), (3.0, 0.2, -0.3), (0.4, NAN)),  # + acceleration
        (3135, (NAN, NAN, NAN, NAN, 0.1, 0.2), (NAN, NAN, -0.3), None),  # acceleration
        (3576, (1.0, 2.0, NAN, NAN, NAN, NAN), (3.0, NAN, NAN), None),  # DESIGN.md's position mask
        (0b110111111011, None, (3.0, NAN, NAN), None),  # z alone (`fly`): the horizontal group stays as it was
    ],
)
def test_mavsdk_masks_in_local_ned(mask, horizontal, vertical, heading):
    h, v, y = target(mask)
    assert same(h, horizontal) and same(v, vertical) and same(y, heading), (h, v, y)


def test_body_ned_rotates_velocity_by_the_heading_and_refuses_positions():
    # MAVSDK's set_velocity_body: frame 8, mask 1479 (velocity + yaw rate); 1 m/s forward heading east → east
    h, v, y = target(1479, vel=(1.0, 0.5, 0.0), frame=8)
    assert h[2:4] == pytest.approx((-0.5, 1.0)) and math.isnan(h[0]) and same(v, (NAN, -0.0, NAN))
    assert same(y, (NAN, 0.1))
    with pytest.raises(SetpointError, match=r"BODY_NED \(8\): positions are not supported"):
        target(2552, frame=8)


def test_global_frames_convert_through_the_map_projection():
    lat, lon = ned_to_geodetic(30.0, -40.0, ORIGIN[0], ORIGIN[1])
    pos = (lat * 1e7, lon * 1e7, 498.0)
    h, v, _ = target(2552, pos=pos, frame=5)  # altitude AMSL
    assert h[:2] == pytest.approx((30.0, -40.0), abs=0.02) and v[0] == pytest.approx(10.0)
    _, v, _ = target(2552, pos=(pos[0], pos[1], 10.0), frame=6)  # above home (0.5 m above the origin)
    assert v[0] == pytest.approx(10.5)
    _, v, _ = target(2552, pos=(pos[0], pos[1], 10.0), frame=11)  # above the ground
    assert v[0] == pytest.approx(10.0)


@pytest.mark.parametrize(
    "kw, message",
    [
        ({"frame": 7}, "frame 7: supported are LOCAL_NED (1), BODY_NED (8)"),
        ({"pos": (NAN, 2.0, -3.0)}, "x = nan: expected a finite number (or ignore it: type_mask bit 1)"),
        ({"vel": (0.5, math.inf, 0.0), "mask": 2503}, "vy = inf: expected a finite number"),
        ({"mask": 2048 | 512}, "force setpoints (type_mask bit 512) are not supported"),
        ({"pos": (0.0, 0.0, -2000.0)}, "altitude 2000 m; allowed: 0..1000 m"),
        ({"pos": (0.0, 0.0, 1.0)}, "altitude -1 m; allowed: 0..1000 m"),
        ({"vel": (12.0, 2.0, 0.0), "mask": 2503}, "horizontal speed 12.2 m/s; allowed: up to 12 m/s"),
        ({"vel": (0.0, 0.0, -3.5), "mask": 2503}, "vz = -3.5 m/s; allowed: -3..1.5 m/s"),
        ({"vel": (0.0, 0.0, 2.0), "mask": 2503}, "vz = 2 m/s"),
        ({"pos": (1e9, 0.0, 100.0), "frame": 5}, "lat_int = 1e+09: expected a latitude in [-90, 90]"),
        (
            {"f": Frame(ORIGIN, max_distance=100.0), "pos": (100.0, 10.0, -3.0)},
            "100.5 m from home; allowed: up to 100 m, parameter GF_MAX_HOR_DIST",
        ),
    ],
)
def test_refusals_name_the_field_the_value_and_what_is_allowed(kw, message):
    kw.setdefault("mask", 2552)
    with pytest.raises(SetpointError) as err:
        target(**kw)
    assert message in str(err.value)


def test_reposition_keeps_nan_coordinates_and_checks_the_location():
    lat, lon = ned_to_geodetic(20.0, 0.0, ORIGIN[0], ORIGIN[1])
    x, y, alt = reposition(lat, lon, 488.0 + 7.0, 5, F)
    assert (x, y, alt) == pytest.approx((20.0, 0.0, 7.0), abs=0.01)
    x, y, alt = reposition(NAN, NAN, 7.0, 6, F)  # altitude only, above home
    assert math.isnan(x) and math.isnan(y) and alt == 7.5
    with pytest.raises(SetpointError, match=r"Reposition refused: latitude 91 deg; allowed: \[-90, 90\]"):
        reposition(91.0, 0.0, NAN, 5, F)
    with pytest.raises(SetpointError, match="give latitude and longitude both"):
        reposition(lat, NAN, NAN, 5, F)
    with pytest.raises(SetpointError, match="frame 1; supported are GLOBAL"):
        reposition(lat, lon, NAN, 1, F)
