"""What the MAVSDK tests share: connecting as MAVSDK's examples do, and reading its telemetry streams."""

from __future__ import annotations

import asyncio

from mavsdk.asyncio import Mavsdk
from mavsdk.asyncio.plugins.telemetry import TelemetryAsync


async def first(stream):
    async for item in stream:
        return item


async def until(stream, cond, timeout: float):
    async def scan():
        async for item in stream:
            if cond(item):
                return item

    return await asyncio.wait_for(scan(), timeout)


async def autopilot(m: Mavsdk, port: int):
    """The first autopilot MAVSDK sees on UDP ``port`` (it listens, as on PX4's 14540)."""
    await m.add_any_connection(f"udpin://127.0.0.1:{port}")
    system = await m.first_autopilot(timeout_s=20.0)
    assert system is not None, "MAVSDK saw no autopilot"
    return system


async def healthy(tel: TelemetryAsync, timeout: float = 30.0):
    """Wait as MAVSDK's examples wait before they arm: until global position and home are OK."""

    async def ready():
        async for health in tel.subscribe_health():
            if health.is_global_position_ok and health.is_home_position_ok:
                return health

    return await asyncio.wait_for(ready(), timeout)


async def texts(system, said: list[str]) -> None:
    """Every STATUSTEXT the vehicle says, appended to ``said`` (run it as a task)."""
    async for t in TelemetryAsync(system).subscribe_status_text():
        said.append(t.text)
