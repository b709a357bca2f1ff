"""A mission's flight (``quadsitl gcs --mission FILE``, :mod:`groundstation.mission_files`): a ground station
(:class:`groundstation.station.GroundStation`) that uploads the mission through the mission protocol
(:mod:`groundstation.mission_upload`; a refusal fails the flight, naming the result), arms, starts it (AUTO.MISSION:
``DO_SET_MODE`` 4/4), and watches ``MISSION_ITEM_REACHED`` and ``MISSION_CURRENT``. A mission that ends with
``NAV_RETURN_TO_LAUNCH`` or ``NAV_LAND`` is over when the vehicle has landed and disarmed; any other is landed where it
ends (``MAV_CMD_NAV_LAND``) once ``MISSION_CURRENT`` says complete (mission_state 5). ``--duration`` bounds the
mission in simulated seconds. ``mission.json`` gets the items and the simulated time (t of telemetry.csv, 0 at
arming) at which each ``MISSION_ITEM_REACHED`` arrived.
"""

from __future__ import annotations

import json
import sys
import time

from groundstation import mission_files
from groundstation.mission_upload import MissionUpload
from groundstation.progress import FlightProgress
from groundstation.station import (
    COMMAND_RETRY,
    UNNEEDED_IN_FLIGHT,
    UNNEEDED_STREAMS,
    GcsError,
    GroundStation,
    Phase,
)
from quadsitl.frames import PX4_HOME
from quadsitl.wire import mavlink

MISSION_STATE_COMPLETE = 5  # MISSION_CURRENT's mission_state: the mission is complete


class MissionFlight(GroundStation):
    """A ground station flying ``args.mission`` (loaded when made: :class:`groundstation.station.GroundStation`)."""

    def send_mission_item(self, seq: int) -> None:
        """The mission's item ``seq`` as MISSION_ITEM_INT."""
        fields = self.mission.items[seq].message_fields()
        self.send(mavlink.MAVLink_mission_item_int_message(*self.target, **fields))

    def fly(self) -> int:
        """Upload the mission through the protocol (:class:`groundstation.mission_upload.MissionUpload`), arm, start
        it (AUTO.MISSION), fly it to its end and land; write the results (mission.json too) → the exit status."""
        args, mission = self.args, self.mission
        n_items = len(mission.items)
        phase = Phase.CONNECT
        deadline = time.monotonic() + args.timeout
        last_hb, last_cmd, upload = 0.0, 0.0, None
        wall_start, flight_wall_start = time.monotonic(), None
        while phase is not Phase.DONE:
            now = time.monotonic()
            if now > deadline:
                raise GcsError(f"timed out after {args.timeout:g} s (wall) in phase '{phase.value}'")
            self.poll()
            self.logger.drain()
            flight_t = self.logger.flight_time()
            for r in self.reached:
                if r["t"] is None:
                    r["t"] = round(max(flight_t, 0.0), 6)
            last_hb = self.heartbeat(now, last_hb)
            if phase is Phase.CONNECT and self.heard:
                self.stop_streams(UNNEEDED_STREAMS)
                phase, upload = Phase.UPLOAD, MissionUpload(n_items, now)
            elif phase is Phase.UPLOAD:
                step = upload.step(now, self.requested, self.mission_ack)
                self.requested.clear()
                for seq in step.items:
                    self.send_mission_item(seq)
                if step.error is not None:
                    raise GcsError(step.error)
                if step.count:
                    self.send(mavlink.MAVLink_mission_count_message(*self.target, n_items, 0))
                if step.done:
                    if not args.quiet:
                        print(f"gcs: uploaded {n_items} mission items from {mission.path}", file=sys.stderr)
                    phase = Phase.PREARM
            elif phase is Phase.PREARM and self.logger.last_status is not None and self.armable:
                # never fly what cannot be recorded, nor arm before the pre-arm check
                phase, last_cmd = Phase.ARMING, 0.0
            elif phase is Phase.ARMING:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arming", now, last_cmd, 1.0)
                if done:
                    phase, last_cmd = Phase.STARTING, 0.0
            elif phase is Phase.STARTING:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_DO_SET_MODE, "mission mode", now, last_cmd,
                                                     mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4)  # fmt: skip
                if done:
                    self.stop_streams(UNNEEDED_IN_FLIGHT)
                    phase, flight_wall_start = Phase.FLYING, now
                    self.progress = FlightProgress(self.duration, enabled=not args.quiet, label="gcs: mission")
            elif phase in (Phase.FLYING, Phase.LANDING):
                status = self.logger.last_status
                if status is not None and not status["armed"] and self.logger.last_armed_tick >= 0:
                    self.flight_rate = (flight_t, now - flight_wall_start)
                    self.progress.update(flight_t)
                    self.progress.close()
                    phase = Phase.DONE
                elif flight_t > self.duration:  # keep what was flown: the telemetry and the items reached
                    message = self._unfinished(flight_t)
                    self.save_partial("the mission overran --duration")
                    self.write_mission_json(disarmed=False)
                    raise GcsError(message)
                elif phase is Phase.FLYING:
                    self.progress.update(flight_t)
                    complete = self.mission_state is not None and self.mission_state[1] == MISSION_STATE_COMPLETE
                    if complete and not mission.lands:
                        phase, last_cmd = Phase.LANDING, 0.0
                elif (
                    now - last_cmd > COMMAND_RETRY
                    and self.acks.get(mavlink.MAV_CMD_NAV_LAND) != mavlink.MAV_RESULT_ACCEPTED
                ):
                    if self.acks.get(mavlink.MAV_CMD_NAV_LAND) not in (None, mavlink.MAV_RESULT_ACCEPTED):
                        raise GcsError(f"landing refused (MAV_RESULT {self.acks[mavlink.MAV_CMD_NAV_LAND]})")
                    self.command(mavlink.MAV_CMD_NAV_LAND)
                    last_cmd = now
        # the flight: every armed tick, up to the disarm
        self.duration = (self.logger.last_armed_tick - self.logger.flight_start_tick + 1) * self.period
        self.write_mission_json()
        return self.finish(time.monotonic() - wall_start)

    def _unfinished(self, flight_t: float) -> str:
        """Why a mission that overran ``--duration`` failed, at flight time ``flight_t`` [s]: one line."""
        where = "no MISSION_CURRENT yet"
        if self.mission_state is not None:
            seq, state = self.mission_state
            where = f"current item {seq} of {len(self.mission.items)}, mission_state {state}"
        return (f"the mission did not end within --duration {self.duration:g} simulated s ({where}, "
                f"{len({r['seq'] for r in self.reached})} items reached, after {flight_t:.1f} s)")  # fmt: skip

    def write_mission_json(self, disarmed: bool = True) -> None:
        """mission.json (:func:`groundstation.mission_files.report`): the reached times are telemetry.csv's t (0 at
        arming) when each MISSION_ITEM_REACHED arrived; ``disarmed`` False for a flight cut short."""
        doc = mission_files.report(self.mission, self.args.home or PX4_HOME, self.reached,
                                   self.duration if disarmed else None)  # fmt: skip
        (self.out / "mission.json").write_text(json.dumps(doc, indent=2) + "\n")
