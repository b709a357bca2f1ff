"""A mission's flight (``quadsitl gcs --mission FILE``, :mod:`groundstation.mission_files`): a ground station
(:class:`groundstation.station.GroundStation`) that uploads the mission through the mission protocol
(:mod:`groundstation.mission_upload`; a refusal fails the flight, naming the result), selects AUTO.MISSION
(``DO_SET_MODE`` 4/4) and arms, which starts it, as PX4 does; then follows the telemetry. A mission that does
not end with ``NAV_RETURN_TO_LAUNCH`` or ``NAV_LAND`` is uploaded with a ``NAV_LAND`` after its last item
(:attr:`groundstation.mission_files.Mission.flown`: it lands where it ends). The flight is over when the vehicle has
landed and disarmed. ``--duration`` bounds the mission in simulated seconds. ``mission.json`` gets the items and the
simulated time (t of telemetry.csv, 0 at arming) of the tick at which each was reached, from the vehicle's mission
document over Zenoh (:mod:`quadsitl.telemetry`), exact where ``MISSION_ITEM_REACHED`` arrives when it arrives.

With ``--arm-at T`` (``quadsitl fly``, whose plant holds its clock at T until the vehicle arms) the mode is selected
and the vehicle armed once its clock stands at T: every run starts its mission at the same tick. Nothing this ground
station sends after that changes the flight, so a lockstep flight is the same to the byte on any machine, however
late the ground station.
"""

from __future__ import annotations

import json
import sys
import time

from groundstation import mission_files
from groundstation.mission_upload import MissionUpload
from groundstation.progress import FlightProgress
from groundstation.station import (
    UNNEEDED_IN_FLIGHT,
    GcsError,
    GroundStation,
    Phase,
)
from quadsitl.frames import PX4_HOME
from quadsitl.wire import mavlink

UPLOADED = {0: "mission", 1: "geofence", 2: "rally point"}  # what each mission_type's upload is called


class MissionFlight(GroundStation):
    """A ground station flying ``args.mission`` (loaded when made: :class:`groundstation.station.GroundStation`)."""

    def uploads(self) -> list[tuple[int, tuple]]:
        """What is uploaded, in QGroundControl's order: (mission_type, items) of the mission, then the plan's geofence
        and rally points when it has them."""
        m = self.mission
        return [(0, m.flown)] + [(kind, items) for kind, items in ((1, m.fence), (2, m.rally)) if items]

    def send_mission_item(self, items: tuple, seq: int) -> None:
        """Item ``seq`` of ``items`` as MISSION_ITEM_INT."""
        self.send(mavlink.MAVLink_mission_item_int_message(*self.target, **items[seq].message_fields()))

    def fly(self) -> int:
        """Upload the mission through the protocol (:class:`groundstation.mission_upload.MissionUpload`), select
        AUTO.MISSION, arm (which starts it), fly it to its landing; write the results (mission.json too) → the exit
        status."""
        args, mission = self.args, self.mission
        uploads = self.uploads()
        kind, items = uploads.pop(0)
        arm_tick = None if args.arm_at is None else round(args.arm_at / self.period)
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
            last_hb = self.heartbeat(now, last_hb)
            if phase is Phase.CONNECT and self.heard:
                self.take_link()
                phase, upload = Phase.UPLOAD, MissionUpload(len(items), now)
            elif phase is Phase.UPLOAD:
                step = upload.step(now, self.requested, self.mission_ack)
                self.requested.clear()
                for seq in step.items:
                    self.send_mission_item(items, seq)
                if step.error is not None:
                    why = f": the vehicle says {self.said[-1]!r}" if self.said else ""
                    raise GcsError(step.error.replace("mission", UPLOADED[kind], 1) + why)
                if step.count:
                    self.send(mavlink.MAVLink_mission_count_message(*self.target, len(items), kind))
                if step.done:
                    if not args.quiet:
                        print(f"gcs: uploaded {len(items)} {UPLOADED[kind]} items from {mission.path}",
                              file=sys.stderr)  # fmt: skip
                    self.mission_ack = None
                    if uploads:  # the next: the geofence, the rally points
                        kind, items = uploads.pop(0)
                        self.upload_type, upload = kind, MissionUpload(len(items), now)
                    else:
                        phase = Phase.PREARM
            elif phase is Phase.PREARM and self.logger.last_status is not None and self.armable:
                # never fly what cannot be recorded, nor arm before the pre-arm check (nor, --arm-at, before then)
                if arm_tick is None or self.logger.last_tick >= arm_tick:
                    phase, last_cmd = Phase.STARTING, 0.0
            elif phase is Phase.STARTING:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_DO_SET_MODE, "mission mode", now, last_cmd,
                                                     mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 4)  # fmt: skip
                if done:
                    phase, last_cmd = Phase.ARMING, 0.0
            elif phase is Phase.ARMING:
                done, last_cmd = self.until_accepted(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, "arming", now, last_cmd, 1.0)
                if done:
                    self.stop_streams(UNNEEDED_IN_FLIGHT)
                    phase, flight_wall_start = Phase.FLYING, now
                    self.progress = FlightProgress(self.duration, enabled=not args.quiet, label="gcs: mission")
            elif phase is Phase.FLYING:
                status = self.logger.last_status
                if status is not None and not status["armed"] and self.logger.last_armed_tick >= 0:
                    self.flight_rate = (flight_t, now - flight_wall_start)
                    self.progress.update(flight_t)
                    self.progress.close()
                    phase = Phase.DONE
                elif flight_t > self.duration:  # keep what was flown: the telemetry and the items reached
                    self.save_partial("the mission overran --duration")
                    self.write_mission_json(disarmed=False)
                    raise GcsError(self._unfinished(flight_t))
                else:
                    self.progress.update(flight_t)
        # the flight: every armed tick, up to the disarm
        self.duration = (self.logger.last_armed_tick - self.logger.flight_start_tick + 1) * self.period
        self.write_mission_json()
        return self.finish(time.monotonic() - wall_start)

    def _unfinished(self, flight_t: float) -> str:
        """Why a mission that overran ``--duration`` failed, at flight time ``flight_t`` [s]: one line."""
        where = "no mission document yet"
        doc = self.logger.mission  # as mission.json: what the telemetry had when the flight was cut short
        if doc is not None:
            where = f"current item {doc['current']} of {len(self.mission.items)}, mission_state {doc['state']}"
        return (f"the mission did not end within --duration {self.duration:g} simulated s ({where}, "
                f"{len({r['seq'] for r in self.logger.reached()})} items reached, after {flight_t:.1f} s)")  # fmt: skip

    def write_mission_json(self, disarmed: bool = True) -> None:
        """mission.json (:func:`groundstation.mission_files.report`): the reached times are telemetry.csv's t (0 at
        arming) of the tick each item was reached at, as the vehicle's mission document says
        (:meth:`groundstation.logger.TelemetryLogger.reached`); ``disarmed`` False for a flight cut short."""
        doc = mission_files.report(self.mission, self.args.home or PX4_HOME, self.logger.reached(),
                                   self.duration if disarmed else None)  # fmt: skip
        (self.out / "mission.json").write_text(json.dumps(doc, indent=2) + "\n")
