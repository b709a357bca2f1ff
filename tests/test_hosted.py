"""``quadsitl up --vehicles N --hosted``: every vehicle's autopilot in one process (:mod:`autopilot.host`), each
behaving as one of its own would: its own MAVLink identity on its own ports (MAVSDK finds it there alone), its own
parameters, and its own failsafes (one vehicle's ground station lost trips that vehicle's datalink failsafe only)."""

import asyncio
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from autopilot.host import vehicles_of
from quadsitl.process_util import children_of
from tests.mavclient import Client, fleet_up

LAND = (4 << 16) | (6 << 24)  # PX4's AUTO.LAND in HEARTBEAT's custom_mode
TEXT = "Ground station lost: no heartbeat for 1 s; action: land"


def cmdlines(pid: int) -> list[bytes]:
    out = []
    for child in children_of(pid):
        try:
            out.append(Path(f"/proc/{child}/cmdline").read_bytes())
        except OSError:
            continue
    return out


def test_the_host_takes_each_autopilots_command_line_between_double_dashes():
    assert vehicles_of(["--", "--preset", "x500", "--", "--system-id", "2"]) == [["--preset", "x500"],
                                                                               ["--system-id", "2"]]  # fmt: skip
    for bad in ([], ["--preset", "x500"], ["--", "--preset", "x500", "--"], ["--", "--"]):
        with pytest.raises(ValueError):
            vehicles_of(bad)


@pytest.mark.timeout(240)
def test_hosted_vehicles_share_one_process_and_keep_their_own_identity_parameters_and_failsafes():
    with fleet_up(2, "--hosted") as fleet:
        # MAVSDK on vehicle 2's offboard port finds system id 2 alone, as with a process each
        async def mavsdk_ids() -> list[int]:
            from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

            async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
                await m.add_any_connection(f"udpin://127.0.0.1:{fleet.api_port + 1}")
                assert await m.first_autopilot(timeout_s=90.0) is not None  # the first start compiles
                await asyncio.sleep(2.0)  # time to hear anyone else, if anyone else streamed here
                return sorted([await s.get_system_id() for s in await m.get_systems()])

        assert asyncio.run(mavsdk_ids()) == [2]
        # one autopilot process for both vehicles, beside the plant
        lines = cmdlines(fleet.proc.pid)
        assert len([c for c in lines if b"autopilot.host" in c]) == 1, lines
        assert not [c for c in lines if b"-m\0autopilot\0" in c], lines

        one, two = Client(fleet.api_port), Client(fleet.api_port + 1)  # each vehicle's offboard link
        try:
            one.connect(timeout=30)
            two.connect(timeout=30)
            assert one.latest["HEARTBEAT"].get_srcSystem() == 1 and two.latest["HEARTBEAT"].get_srcSystem() == 2
            # parameters of their own: the same one set to two values
            for c, system, seconds in ((one, 1, 1.0), (two, 2, 3.0)):
                assert c.param_set("NAV_DLL_ACT", 2, system=system).param_value == 2.0
                assert c.param_set("COM_DL_LOSS_T", seconds, system=system).param_value == seconds
                assert c.param_set("COM_DISARM_PRFLT", -1, system=system).param_value == -1.0  # armed on the ground
            for c, system in ((one, 1), (two, 2)):
                c.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, system=system).result == M.MAV_RESULT_ACCEPTED
            # vehicle 1's ground station goes silent, vehicle 2's keeps its heartbeat: vehicle 1 alone lands
            end = time.monotonic() + 8
            while time.monotonic() < end and not any(TEXT in t for t in one.texts):
                two.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                one.pump(0.2)
                two.pump(0.2)
            assert any(TEXT in t for t in one.texts), one.texts
            one.wait("HEARTBEAT", lambda m: m.custom_mode == LAND and m.get_srcSystem() == 1, timeout=5)
            for _ in range(10):  # 4 s: longer than vehicle 2's own datalink timeout, its ground station heard
                two.conn.mav.heartbeat_send(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0)
                two.pump(0.4)
            assert not [t for t in two.texts if "Ground station lost" in t], two.texts
            beat = two.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, timeout=5)
            assert beat.get_srcSystem() == 2 and beat.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED
            assert beat.custom_mode != LAND
        finally:
            one.close()
            two.close()
