"""Wind changed while ``quadsitl up`` flies: a JSON object on the Zenoh key ``quadsitl/<vehicle>/wind`` reaches the
plant (sitl/wind_link.py), which answers on ``quadsitl/<vehicle>/wind/now``; a real Zenoh session publishes it
and a raw pymavlink client flies the vehicle and watches where the wind puts it."""

import contextlib
import json
import math
import queue

import pytest
import zenoh

from quadsitl import telemetry
from tests.mavclient import Client, M, quadsitl_up

NAN = math.nan
HOLD = (4 << 16) | (3 << 24)
OFFSET = 0.25 * 5.0 / (2.0 * 1.0 * 2.0)  # K2·w/(m·k9·k10): the x500's drift in 5 m/s without integral action [m]


def near(c: Client, target: tuple[float, float, float], tolerance: float, timeout: float = 30.0) -> None:
    c.wait("LOCAL_POSITION_NED", lambda p: math.dist((p.x, p.y, -p.z), target) < tolerance, timeout)


@pytest.mark.timeout(120)
def test_a_wind_published_on_zenoh_blows_the_flying_vehicle_downwind_and_a_bad_one_changes_nothing():
    with quadsitl_up("--preset", "x500", "--speed", "8") as v:
        c = Client(v.gcs_port)
        session = zenoh.open(telemetry.zenoh_config(connect=[v.zenoh]))
        answers: queue.Queue = queue.Queue()
        try:
            session.declare_subscriber("quadsitl/v1/wind/now", lambda s: answers.put(json.loads(s.payload.to_bytes())))
            c.wait_armable()
            assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
            c.conn.mav.command_int_send(1, 1, 0, M.MAV_CMD_NAV_TAKEOFF, 0, 0, NAN, NAN, NAN, NAN, 0, 0, 491.0)
            c.wait("HEARTBEAT", lambda m: m.custom_mode == HOLD, 30)
            near(c, (0.0, 0.0, 3.0), 0.02)

            # refused: the answer names the key, the value and the range; the air stays calm. (Said until the
            # first answer: Zenoh's peers take a second or two to find each other's subscriptions.) The plant's own
            # word at its start may be in the queue before it (a plant that started after this subscriber: CI): the
            # wind in effect, calm.
            refused = None
            for _ in range(40):
                session.put("quadsitl/v1/wind", '{"speed_m_s": 80, "from_deg": 270}')
                with contextlib.suppress(queue.Empty):
                    refused = answers.get(timeout=0.5)
                    while "refused" not in refused:
                        assert refused["speed_m_s"] == 0.0, refused
                        refused = answers.get(timeout=5)
                    break
            while not answers.empty():
                answers.get()
            assert refused is not None, "the plant never answered on quadsitl/v1/wind/now"
            assert refused["refused"] == "wind.speed_m_s = 80: expected a number in [0, 50] m/s"
            assert refused["speed_m_s"] == 0.0
            session.put("quadsitl/v1/wind", b"\xff not json")
            assert answers.get(timeout=10)["refused"].startswith("wind: not JSON")

            # 5 m/s from the west: the vehicle settles downwind (east) by the offset of its drag
            session.put("quadsitl/v1/wind", '{"speed_m_s": 5, "from_deg": 270}')
            now = answers.get(timeout=10)
            assert "refused" not in now and (now["speed_m_s"], now["from_deg"]) == (5.0, 270.0)
            near(c, (0.0, OFFSET, 3.0), 0.01)
            c.pump(1.0)
            near(c, (0.0, OFFSET, 3.0), 0.01, timeout=1.0)  # settled there, not passing through
            # a change of one key keeps the others: calm again by speed alone, and back over the origin
            session.put("quadsitl/v1/wind", '{"speed_m_s": 0}')
            assert answers.get(timeout=10)["from_deg"] == 270.0
            near(c, (0.0, 0.0, 3.0), 0.01)
            assert v.proc.poll() is None  # everything still runs
        finally:
            session.close()
            c.close()


def test_ups_banner_says_the_wind_and_where_to_change_it():
    import argparse

    from groundstation.launcher import banner, describe_wind
    from quadsitl.config import WindParams, load_preset

    assert describe_wind(WindParams()) == "calm"
    gusty = WindParams(5.0, 270.0, "light", 3.0, 1.0, 2.0, 0.0, 0, (0.0, 0.0, 1.5))
    assert describe_wind(gusty) == ("5 m/s from 270°, light turbulence, a 3 m/s gust from 0° 2 s after lift-off, a "
                                    "force of (0, 0, 1.5) N, NED")  # fmt: skip
    args = argparse.Namespace(controller=None, mode="lockstep", speed=1.0, system_id=1, gcs_remote=None,
                              api_remote=None, no_zenoh=False, zenoh_listen="tcp/127.0.0.1:7447")  # fmt: skip
    lines = banner(load_preset("x500"), args).splitlines()
    assert "  wind:            calm; change it with JSON on the Zenoh key quadsitl/v1/wind" in lines
    args.no_zenoh = True
    assert "  wind:            calm" in banner(load_preset("x500"), args).splitlines()
