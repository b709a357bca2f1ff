"""Fleets: ``quadsitl up --vehicles N`` by PX4's multi-vehicle conventions. The plan alone (ports, system ids, names,
homes on a grid, per-vehicle presets, refusals), then a real fleet: one ground station on the shared port sees
every vehicle, commands addressed to one system id move only that vehicle, MAVSDK on one vehicle's offboard
port finds that vehicle only, and Zenoh carries every vehicle's telemetry under its own name."""

from __future__ import annotations

import asyncio
import math
import socket
import subprocess
import sys
import time

import pytest

from groundstation.fleet import MAX_VEHICLES, plan_fleet
from quadsitl.cli_util import UsageError, parse_vehicle_presets
from quadsitl.frames import geodetic_to_ned
from tests.mavclient import Client, M, fleet_up


def test_px4_port_plan_system_ids_and_names():
    fleet = plan_fleet(12, preset="paper")
    assert [v.system_id for v in fleet] == list(range(1, 13)) and [v.name for v in fleet] == [
        f"v{i}" for i in range(1, 13)
    ]
    assert [v.gcs_listen for v in fleet] == [f"127.0.0.1:{18570 + i}" for i in range(12)]
    assert {v.gcs_remote for v in fleet} == {"127.0.0.1:14550"}  # one ground station sees the fleet
    assert [v.api_listen for v in fleet] == [f"127.0.0.1:{14580 + i}" for i in range(12)]
    assert [v.api_remote for v in fleet] == [f"127.0.0.1:{14540 + i}" for i in range(10)] + ["127.0.0.1:14549"] * 2
    # explicit addresses are the first vehicle's; the others count up from them
    f = plan_fleet(3, preset="paper", first_system_id=10, gcs_listen="0.0.0.0:20000", api_remote="10.0.0.2:30000")
    assert [v.system_id for v in f] == [10, 11, 12] and [v.name for v in f] == ["v1", "v2", "v3"]
    assert [v.gcs_listen for v in f] == ["0.0.0.0:20000", "0.0.0.0:20001", "0.0.0.0:20002"]
    assert [v.api_remote for v in f] == ["10.0.0.2:30000", "10.0.0.2:30001", "10.0.0.2:30002"]
    assert plan_fleet(2, preset="paper", api_remote="none")[1].api_remote == "none"
    anywhere = plan_fleet(3, preset="paper", gcs_listen="127.0.0.1:0", api_listen="127.0.0.1:0")  # any free ports
    assert {v.gcs_listen for v in anywhere} == {v.api_listen for v in anywhere} == {"127.0.0.1:0"}


def test_vehicles_start_on_a_grid_each_with_its_own_home():
    home = (47.0, 8.0, 400.0)
    fleet = plan_fleet(5, preset="paper", home=home, spacing=4.0)  # 3 columns: two rows
    assert [v.offset for v in fleet] == [(0, 0), (0, 4), (0, 8), (4, 0), (4, 4)]
    assert fleet[0].home == home
    for v in fleet:
        north, east = geodetic_to_ned(v.home[0], v.home[1], home[0], home[1])
        assert (north, east) == (pytest.approx(v.offset[0], abs=1e-6), pytest.approx(v.offset[1], abs=1e-6))
        assert v.home[2] == 400.0
    separations = [math.dist(a.offset, b.offset) for a in fleet for b in fleet if a is not b]
    assert min(separations) == pytest.approx(4.0)


def test_per_vehicle_presets():
    presets = parse_vehicle_presets(["2=x500", "3 = my.toml"], 3)
    assert presets == {2: "x500", 3: "my.toml"}
    fleet = plan_fleet(3, preset="paper", vehicle_presets=presets)
    assert [v.preset for v in fleet] == ["paper", "x500", "my.toml"]


@pytest.mark.parametrize(
    ("call", "message"),
    [
        (lambda: plan_fleet(0, preset="p"), f"--vehicles 0: expected an integer in 1..{MAX_VEHICLES}"),
        (lambda: plan_fleet(MAX_VEHICLES + 1, preset="p"), f"--vehicles {MAX_VEHICLES + 1}: expected"),
        (lambda: plan_fleet(10, preset="p", first_system_id=250), "--system-id 250 with --vehicles 10: system ids "
         "250..259 must lie in 1..255"),
        (lambda: plan_fleet(2, preset="p", spacing=0.0), "--spacing 0.0: expected metres in [0.5, 1000]"),
        (lambda: plan_fleet(2, preset="p", spacing=math.nan), "--spacing nan: expected metres"),
        (lambda: plan_fleet(3, preset="p", gcs_listen="127.0.0.1:14579"), "--gcs-listen 127.0.0.1:14580: vehicle 2 "
         "would bind port 14580, which vehicle 1's --api-listen already binds"),
        (lambda: plan_fleet(3, preset="p", gcs_listen="127.0.0.1:65534"), "--gcs-listen 127.0.0.1:65534: vehicle 3 "
         "would need port 65536, beyond 65535"),
        (lambda: parse_vehicle_presets(["4=x500"], 3), "--vehicle-preset '4=x500': vehicle 4 is not in the fleet "
         "(1..3, --vehicles 3)"),
        (lambda: parse_vehicle_presets(["x500"], 3), "--vehicle-preset 'x500': expected K=PRESET"),
        (lambda: parse_vehicle_presets(["2=x500", "2=paper"], 3), "--vehicle-preset '2=paper': vehicle 2 already "
         "has preset 'x500'"),
    ],
)  # fmt: skip
def test_bad_fleet_input_is_refused_naming_the_option(call, message):
    with pytest.raises(UsageError) as err:
        call()
    assert str(err.value).startswith(message)


def test_the_cli_refuses_a_bad_fleet_before_anything_starts():
    def up(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "groundstation.cli", "up", *args], capture_output=True,
                              text=True, timeout=60)  # fmt: skip

    r = up("--vehicles", "100")
    assert r.returncode == 2 and r.stderr.strip() == (
        f"quadsitl up: error: --vehicles 100: expected an integer in 1..{MAX_VEHICLES}"
    ), r.stderr
    r = up("--vehicles", "2", "--vehicle-preset", "2=nosuch")
    assert r.returncode == 2 and r.stderr.count("\n") == 1 and "--vehicle-preset 2=nosuch" in r.stderr
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as busy:  # vehicle 2's ground link port is taken
        busy.bind(("127.0.0.1", 0))
        port = busy.getsockname()[1]
        r = up("--vehicles", "2", "--gcs-listen", f"127.0.0.1:{port - 1}", "--no-zenoh")
    assert r.returncode == 2 and "(vehicle 2)" in r.stderr and f"127.0.0.1:{port}" in r.stderr, r.stderr


def local_positions(c: Client, seconds: float) -> dict[int, tuple[float, float, float]]:
    """The newest LOCAL_POSITION_NED (x, y, z) of every system heard within ``seconds``."""
    out: dict[int, tuple[float, float, float]] = {}
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        m = c.conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=0.1)
        if m is not None:
            out[m.get_srcSystem()] = (m.x, m.y, m.z)
    return out


@pytest.mark.timeout(180)
def test_a_fleet_of_three_one_ground_station_commands_reach_only_their_vehicle():
    """Three vehicles: the shared ground-station port hears three system ids; arming and a takeoff addressed to
    system id 2 climb vehicle 2 alone; MAVSDK on vehicle 3's offboard port finds system id 3 only; Zenoh carries
    v1, v2 and v3."""
    import zenoh

    from quadsitl import telemetry

    with fleet_up(3) as fleet:
        c = Client(fleet.gcs_port)
        session = None
        try:
            heard: set[int] = set()
            end = time.monotonic() + 90  # the first start compiles the equations once
            while time.monotonic() < end and heard != {1, 2, 3}:
                c.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                m = c.conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.3)
                if m is not None and m.get_srcComponent() == 1:
                    heard.add(m.get_srcSystem())
            assert heard == {1, 2, 3}

            session = zenoh.open(telemetry.zenoh_config(connect=[fleet.zenoh]))
            names: set[str] = set()
            sub = session.declare_subscriber("quadsitl/*/status", lambda s: names.add(str(s.key_expr).split("/")[1]))
            c.wait("SYS_STATUS", lambda m: m.get_srcSystem() == 2 and m.onboard_control_sensors_health
                   & M.MAV_SYS_STATUS_PREARM_CHECK, 30)  # fmt: skip
            c.conn.mav.command_long_send(2, 1, M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0)
            ack = c.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_COMPONENT_ARM_DISARM, 5)
            assert ack.get_srcSystem() == 2 and ack.result == M.MAV_RESULT_ACCEPTED
            c.conn.mav.command_long_send(
                2, 1, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, math.nan, math.nan, math.nan, math.nan
            )
            ack = c.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_NAV_TAKEOFF, 5)
            assert ack.get_srcSystem() == 2 and ack.result == M.MAV_RESULT_ACCEPTED
            time.sleep(4.0)  # a 2.5 m takeoff at 1.5 m/s (MPC_TKO_SPEED)
            z = local_positions(c, 1.5)
            assert set(z) == {1, 2, 3}
            assert -z[2][2] > 1.5  # vehicle 2 climbed
            assert abs(z[1][2]) < 0.01 and abs(z[3][2]) < 0.01  # the others did not move
            sub.undeclare()
            assert {"v1", "v2", "v3"} <= names

            async def mavsdk_ids() -> list[int]:
                from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

                async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
                    await m.add_any_connection(f"udpin://127.0.0.1:{fleet.api_port + 2}")
                    system = await m.first_autopilot(timeout_s=20.0)
                    assert system is not None
                    await asyncio.sleep(2.0)  # time to hear anyone else, if anyone else streamed here
                    return sorted([await s.get_system_id() for s in await m.get_systems()])

            assert asyncio.run(mavsdk_ids()) == [3]
        finally:
            if session is not None:
                session.close()
            c.close()
