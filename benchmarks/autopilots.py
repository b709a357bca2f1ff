"""The bench's vehicles as processes: an autopilot on free ports (:func:`autopilot_process`), started and warmed up,
and plant runs of a number of ticks against it (:func:`run_plant`), each returning the plant's statistics; and the
equations compiled before the first of them starts (:func:`compile_first`)."""

from __future__ import annotations

import contextlib
import functools
import json
import os
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from quadsitl.children import start_module as _python  # this module's names for them: tests replace them here
from quadsitl.children import stop
from quadsitl.process_util import free_port

GRACE = 5.0  # [s] a bench process's time to end after SIGTERM (an autopilot closes its Zenoh session) before SIGKILL
_stop = functools.partial(stop, grace=GRACE)


class StartedAutopilot:
    """An autopilot process on free ports (:func:`autopilot_process`); unpacks as (plant port, api port, Zenoh
    endpoint, process id). ``start`` False: its ports only, for a process that hosts it (:class:`HostedAutopilots`
    sets ``proc``), which this one never starts again."""

    def __init__(self, env: dict[str, str] | None, system_id: int, taken: set[int],
                 extra: tuple[str, ...] = (), start: bool = True) -> None:  # fmt: skip
        self.env, self.system_id, self.taken, self.extra = env, system_id, taken, extra
        self.attempts = 0
        self.own = start
        if start:
            self.start()
        else:
            self.pick()

    def start(self) -> None:
        """The process started on three free ports (plant, api, Zenoh), none of ``taken``, which they join."""
        self.pick()
        self.proc = _python("autopilot", *self.options(), env=self.env)
        self.attempts += 1

    def pick(self) -> None:
        """Three free ports (plant, api, Zenoh), none of ``taken``, which they join."""
        picks = []
        for kind in (socket.SOCK_DGRAM, socket.SOCK_DGRAM, socket.SOCK_STREAM):
            picks.append(free_port(kind, avoid=self.taken))
            self.taken.add(picks[-1])
        self.plant_port, self.api_port, zenoh_port = picks
        self.endpoint = f"tcp/127.0.0.1:{zenoh_port}"

    def options(self) -> list[str]:
        """The autopilot's command line on its ports (``python -m autopilot`` and :mod:`autopilot.host` take it)."""
        return ["--preset", "paper", "--plant-listen", f"127.0.0.1:{self.plant_port}", "--api-listen",
                f"127.0.0.1:{self.api_port}", "--api-remote", "none", "--gcs-listen", "127.0.0.1:0", "--gcs-remote",
                "none", "--zenoh-listen", self.endpoint, "--system-id", str(self.system_id), *self.extra]  # fmt: skip

    def __iter__(self) -> Iterator:
        return iter((self.plant_port, self.api_port, self.endpoint, self.proc.pid))

    def wait_ready(self, timeout: float = 60.0) -> None:
        """Until it answers a ground station's heartbeat (started and warmed up). One that exits first is started
        again on other ports, up to START_ATTEMPTS times in all: another process (a test beside the bench) may
        bind a picked port before the autopilot does ("Address already in use")."""
        while True:
            try:
                _wait_heartbeat(self.api_port, timeout, alive=lambda: self.proc.poll() is None)
                return
            except AutopilotExitedError:
                if not self.own:
                    raise RuntimeError(f"its host exited with status {self.proc.returncode} while starting") from None
                if self.attempts >= START_ATTEMPTS:
                    raise RuntimeError(f"the autopilot exited with status {self.proc.returncode} while starting, "
                                       f"{self.attempts} times, each on other ports") from None  # fmt: skip
                self.start()


START_ATTEMPTS = 3  # an autopilot's starts in all, each on other ports, before the bench gives up


class HostedAutopilots:
    """``n`` autopilots in one process (:mod:`autopilot.host`, as ``quadsitl up --hosted`` runs a fleet) on free
    ports, system ids 1..n: ``vehicles`` unpack as :class:`StartedAutopilot` do, ``proc`` is the one process."""

    def __init__(self, n: int, taken: set[int]) -> None:
        self.vehicles = [StartedAutopilot(None, i + 1, taken, start=False) for i in range(n)]
        argv = [word for v in self.vehicles for word in ("--", *v.options())]
        self.proc = _python("autopilot.host", *argv)
        for v in self.vehicles:
            v.proc = self.proc

    def wait_ready(self, timeout: float = 120.0) -> None:
        """Until every vehicle answers a ground station's heartbeat."""
        for v in self.vehicles:
            _wait_heartbeat(v.api_port, timeout, alive=lambda: self.proc.poll() is None)


class AutopilotExitedError(RuntimeError):
    """The autopilot's process ended before it answered a heartbeat."""


@contextlib.contextmanager
def autopilot_process(workdir: Path, env: dict[str, str] | None = None, system_id: int = 1,
                      taken: set[int] | None = None, ready: bool = True,
                      extra: tuple[str, ...] = ()) -> Iterator[StartedAutopilot]:  # fmt: skip
    """An autopilot on free ports, unpacking as (plant port, api port, Zenoh endpoint, its process id), and with
    ``ready`` started and warmed up (:meth:`StartedAutopilot.wait_ready`; else call it before its ports are used: a
    fleet's start together). :func:`run_plant` with the api port arms it in hold at the start of each run, as a
    ground station would. (On the ground an autopilot armed in hold idles, as PX4's does, so the control law
    itself, a small part of a tick, does not run.) ``taken``: ports picked for processes that may not have
    bound them yet (a fleet's other autopilots), never picked here; this one's are added to it. ``extra``: more of
    the autopilot's options."""
    ap = StartedAutopilot(env, system_id, set() if taken is None else taken, extra)
    try:
        if ready:
            ap.wait_ready()
        yield ap
    finally:
        _stop(ap.proc)


class RunEndedUnarmedError(RuntimeError):
    """A plant run ended before its autopilot accepted the arm command (a short lockstep run is a fraction of a
    second)."""


def _arm_in_hold(api_port: int, plant: subprocess.Popen) -> None:
    """Arm the autopilot in hold while ``plant`` runs (arming needs a vehicle state; a run that ended left the
    plant-link failsafe in land, so hold first). Each run starts disarmed-then-armed within its first ms."""
    from pymavlink import mavutil

    os.environ.setdefault("MAVLINK20", "1")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255, dialect="common")
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end and plant.poll() is None:
            gcs.mav.command_long_send(1, 1, 176, 0, 1, 4, 3, 0, 0, 0, 0)  # DO_SET_MODE auto/loiter
            gcs.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            deadline = time.monotonic() + 0.02  # again soon: refused until the first state (a run is fast)
            while time.monotonic() < deadline:
                ack = gcs.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.005)
                if ack is not None and ack.command == 400 and ack.result == 0:
                    return
        if plant.poll() is not None:
            raise RunEndedUnarmedError(f"the plant's run ended (status {plant.returncode}) before the autopilot armed")
        raise RuntimeError("the autopilot did not arm within 30 s")
    finally:
        gcs.close()


def run_plant(plant_port: int, workdir: Path, ticks: int, *extra: str, env: dict[str, str] | None = None,
              arm: int | None = None) -> dict:  # fmt: skip
    """A plant run of ``ticks`` against the autopilot at ``plant_port``; with ``arm`` (its api port), armed in hold
    as the run starts (a run that ended before the autopilot armed, seen once in a fan-out warm-up of 5000 ticks,
    is run again, once). Returns the plant's statistics."""
    try:
        return _run_plant(plant_port, workdir, ticks, *extra, env=env, arm=arm)
    except RunEndedUnarmedError:
        return _run_plant(plant_port, workdir, ticks, *extra, env=env, arm=arm)


def _run_plant(plant_port: int, workdir: Path, ticks: int, *extra: str, env: dict[str, str] | None,
               arm: int | None) -> dict:  # fmt: skip
    """One plant run (:func:`run_plant`): its statistics (``--stats``), the plant killed if it is still running."""
    stats = workdir / f"plant-{time.monotonic_ns()}.json"
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--preset", "paper", "--autopilot",
                              f"127.0.0.1:{plant_port}", "--ticks", str(ticks), "--stats", str(stats), *extra],
                             stderr=subprocess.DEVNULL, env=env)  # fmt: skip
    try:
        if arm is not None:
            _arm_in_hold(arm, plant)
        if plant.wait(120) != 0:
            raise RuntimeError(f"the plant exited with status {plant.returncode}")
    finally:
        stop(plant, grace=0)
    return json.loads(stats.read_text())


def _wait_heartbeat(api_port: int, timeout: float = 60.0, alive: Callable[[], bool] | None = None) -> None:
    """Until the autopilot on ``api_port`` answers a ground station's heartbeat with its own (it is started and
    warmed up), so that a real-time plant's ticks are not spent waiting for an autopilot still starting;
    :class:`AutopilotExitedError` as soon as ``alive()`` says its process has gone."""
    from pymavlink import mavutil

    os.environ.setdefault("MAVLINK20", "1")
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{api_port}", source_system=255, dialect="common")
    try:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if alive is not None and not alive():
                raise AutopilotExitedError(f"the autopilot on port {api_port} exited while starting")
            gcs.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            if gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2) is not None:
                return
        raise RuntimeError(f"no heartbeat from the autopilot on port {api_port} in {timeout:g} s")
    finally:
        gcs.close()


def compile_first() -> None:
    """The equations into numba's cache before the first timed section, as ``quadsitl up`` does before a fleet: on
    an empty cache (right after installing, or after any change to the equations) the first autopilot would
    otherwise spend its start compiling and miss the bench's wait for its heartbeat; from the cache it is quick."""
    from groundstation.launcher import compile_once
    from groundstation.progress import announce_if_slow

    with announce_if_slow("quadsitl bench: compiling the equations first (numba's cache keeps them)", after=3.0):
        compile_once(None)
