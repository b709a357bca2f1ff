"""``quadsitl up`` keeps a ULog of each flight, from arming to disarming, as PX4's logger does, and serves it over
MAVLink's log protocol (LOG_*): MAVSDK-Python's ``logfile_download.py`` steps list and download it byte for byte,
pyulog reads it (PX4's topics, the modes flown, the status texts on the simulated clock), and erasing empties the
list. Bad requests get PX4's answer: silence for a log that does not exist, an empty list when there are none."""

from __future__ import annotations

import asyncio
import datetime
import time
from pathlib import Path

import numpy as np
import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.log_files import LogFilesAsync, LogFilesError, LogFilesResult
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
from pyulog import ULog

from autopilot.flight_log import NAV_STATE
from quadsitl.telemetry import MODES
from tests.mavclient import M, armable_client, quadsitl_up
from tests.mavsdk_client import autopilot, healthy, until

MODE = {name: number for number, name in MODES.items()}


async def fly_then_download(port: int, folder: Path) -> dict:
    """Take off, land, then logfile_download.py's steps: list the entries, download each as ``log-<date>.ulog``
    (its name, colons replaced), and erase them all."""
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        tel, action, logs = TelemetryAsync(system), ActionAsync(system), LogFilesAsync(system)
        await healthy(tel)
        try:
            await logs.get_entries()
        except LogFilesError as exc:  # nothing flown yet: MAVSDK says so at once
            seen["before"] = exc.result
        await action.set_takeoff_altitude(3.0)
        await action.arm()
        await action.takeoff()
        await until(tel.subscribe_position(), lambda p: p.relative_altitude_m > 2.9, 30)
        await action.land()
        await until(tel.subscribe_armed(), lambda a: not a, 60)
        await asyncio.sleep(0.5)  # the last batch of rows reaches the log (BATCH_WALL)
        entries = await logs.get_entries()
        seen["entries"] = [(e.id, e.date, e.size_bytes) for e in entries]
        for entry in entries:
            path = folder / f"log-{entry.date.replace(':', '-')}.ulog"
            progress = []
            async for _result, data in logs.download_log_file(entry, str(path)):
                progress.append(data.progress)
            seen.setdefault("downloads", []).append((path, progress))
        await logs.erase_all_log_files()
        await asyncio.sleep(0.5)
        try:
            seen["after_erase"] = len(await logs.get_entries())
        except LogFilesError as exc:
            seen["after_erase"] = exc.result
    return seen


def test_mavsdk_lists_and_downloads_the_flight_log_byte_for_byte_and_erases_it(tmp_path):
    with quadsitl_up("--preset", "x500", "--speed", "3") as v:
        seen = asyncio.run(asyncio.wait_for(fly_then_download(v.api_port, tmp_path), 240))
        logs_left = sorted(v.logs.glob("*/*.ulg"))
        assert v.proc.poll() is None
    assert seen["before"] == LogFilesResult.NO_LOGFILES
    assert len(seen["entries"]) == 1
    entry_id, date, size = seen["entries"][0]
    assert entry_id == 0 and size > 10_000
    written = datetime.datetime.strptime(date, "%Y-%m-%dT%H:%M:%SZ").replace(tzinfo=datetime.UTC)
    assert abs((datetime.datetime.now(datetime.UTC) - written).total_seconds()) < 120  # time_utc: when written
    ((path, progress),) = seen["downloads"]
    assert progress[-1] == 1.0 and progress == sorted(progress)
    data = path.read_bytes()
    assert len(data) == size
    assert seen["after_erase"] == LogFilesResult.NO_LOGFILES and logs_left == []
    log = ULog(str(path))
    topics = {d.name: d.data for d in log.data_list}
    for name in ("vehicle_attitude", "vehicle_local_position", "vehicle_global_position", "actuator_outputs",
                 "vehicle_status", "vehicle_attitude_setpoint", "vehicle_local_position_setpoint"):  # fmt: skip
        assert name in topics, name
    status = topics["vehicle_status"]
    assert set(status["arming_state"].tolist()) == {2}  # the flight: from arming to disarming
    flown = set(status["nav_state"].tolist())
    assert {NAV_STATE[MODE["takeoff"]], NAV_STATE[MODE["land"]]} <= flown
    z = topics["vehicle_local_position"]["z"]
    assert z.min() < -2.8 and z[-1] > -0.2  # took off to 3 m, landed
    t = topics["vehicle_local_position"]["timestamp"]
    assert np.all(np.diff(t)[1:] == 100_000)  # PX4's 100 ms on the simulated clock, after the row that armed
    texts = [(m.timestamp, m.message) for m in log.logged_messages]
    said = [text for _, text in texts]
    assert said[0] == "Armed" and said[-1] == "Landed, disarmed" and "Taking off to 3.0 m" in said, texts
    # on the simulated clock: "Armed" on the tick before the first armed one, the rest within the flight
    assert all(t[0] - 1_000 <= stamp <= t[-1] + 100_000 for stamp, _ in texts), (t[0], t[-1], texts)
    assert log.initial_parameters["MPC_XY_CRUISE"] > 0  # the autopilot's parameters
    battery = topics["battery_status"]  # the x500's 4-cell pack, as PX4 logs it (every 200 ms)
    assert np.all(np.diff(battery["timestamp"])[1:] == 200_000)
    assert 15.0 < battery["voltage_v"].min() < battery["voltage_v"].max() <= 16.8
    assert battery["current_a"].max() > 10.0 and np.all(np.diff(battery["discharged_mah"]) >= 0)
    assert battery["remaining"][0] == 1.0 and battery["connected"].all()


def recv(c, kind: str, timeout: float):
    return c.conn.recv_match(type=kind, blocking=True, timeout=timeout)


@pytest.mark.timeout(120)
def test_bad_log_requests_get_px4s_answers_and_change_nothing():
    with armable_client("--preset", "x500", "--no-zenoh") as c:
        target = (1, M.MAV_COMP_ID_AUTOPILOT1)
        c.conn.mav.log_request_list_send(*target, 0, 0xFFFF)
        entry = recv(c, "LOG_ENTRY", 5)
        assert entry is not None and (entry.num_logs, entry.id, entry.size) == (0, 0, 0)  # no logs: an empty list
        c.conn.mav.log_request_data_send(*target, 3, 0, 0xFFFFFFFF)  # a log that does not exist: no answer
        assert recv(c, "LOG_DATA", 1.5) is None
        c.conn.mav.log_erase_send(*target)  # nothing to erase
        c.conn.mav.log_request_end_send(*target)
        c.conn.mav.log_request_list_send(*target, 0, 0xFFFF)
        entry = recv(c, "LOG_ENTRY", 5)
        assert entry is not None and entry.num_logs == 0
        c.conn.mav.log_request_list_send(2, M.MAV_COMP_ID_AUTOPILOT1, 0, 0xFFFF)  # another system's: not ours
        assert recv(c, "LOG_ENTRY", 1.0) is None
        began = time.monotonic()
        c.wait_armable()  # the vehicle flies on
        assert time.monotonic() - began < 5
