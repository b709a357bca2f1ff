"""Which telemetry message goes out at which tick: the autopilot's message intervals, pure.

Intervals are counted in control ticks, so in lockstep the stream is tied to simulated time (and
deterministic), and in real time it is tied to the wall clock. ``MAV_CMD_SET_MESSAGE_INTERVAL`` sets
one message's interval (µs; −1 stops it, 0 restores the default); ``MAV_CMD_GET_MESSAGE_INTERVAL``
reads it back. HEARTBEAT is not scheduled here: it goes out at 1 Hz of wall time, like PX4's.

Every stream has a phase, as each of PX4's streams keeps its own schedule: the --telemetry-rate messages go out
together (one datagram) at ticks ≡ ``phase`` modulo their interval, with the other messages the compiled tick builds
(:mod:`autopilot.stream_frames`: the positions, the targets, the motor outputs) on the same ticks (a map and a local
plot agree tick for tick), and each of the ones Python builds on a tick of its own between them. Those once all went out
on every 100th tick at 1 kHz: in a real-time fleet all of its autopilots did that Python in the same millisecond, and
the last of them missed its deadline (docs/performance.md#spreading-a-fleets-work-over-the-ticks). An autopilot's
``phase`` follows from its system id (:func:`phase_of`), so a fleet's vehicles stream on different ticks too, and a
lockstep run stays deterministic. The messages with a slot of their own are the ones Python builds (each a trip out of
the compiled loop); a vehicle sends them ``spread`` ticks after vehicle 1 does (:func:`spread_of`), so a fleet's
autopilots make those trips on ticks spread over each 100, where sixteen made all of theirs within the same 25 ticks.
"""

from __future__ import annotations

from collections.abc import Collection

from pymavlink.dialects.v20 import common as mavlink

FAST = (
    mavlink.MAVLINK_MSG_ID_ATTITUDE,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_TARGET,
)
"""The messages ``--telemetry-rate`` sets."""

SLOW_RATES: dict[int, float] = {  # [Hz]
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 10.0,
    # 5 Hz: a GPS receiver's rate (PX4's simulated GPS in Gazebo runs at 5 Hz, DESIGN.md §9); faster would
    # only repeat at more cost what GLOBAL_POSITION_INT says. Every 5 Hz tick is a 10 Hz tick too, so each
    # GPS_RAW_INT leaves in the datagram of a GLOBAL_POSITION_INT built from the same state.
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 5.0,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 10.0,
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 10.0,
    mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: 10.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 2.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 2.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 0.5,  # PX4's rate
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 0.0,  # off until asked for, as on PX4's normal link (MAVSDK's set_rate_imu)
    mavlink.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: 2.0,  # PX4's rate on its normal link; while orbiting
}

# The tick after the fast messages' at which each slow one goes out (an odd offset: never on a fast tick at the
# default 50 Hz). Those the compiled tick builds (autopilot.stream_frames) go with the fast ones, in their datagram:
# GPS_RAW_INT on every other one of GLOBAL_POSITION_INT's ticks.
SLOTS: dict[int, int] = {
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 0,
    mavlink.MAVLINK_MSG_ID_POSITION_TARGET_LOCAL_NED: 0,
    mavlink.MAVLINK_MSG_ID_SERVO_OUTPUT_RAW: 0,
    mavlink.MAVLINK_MSG_ID_ACTUATOR_OUTPUT_STATUS: 0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 9,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 11,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 13,
    mavlink.MAVLINK_MSG_ID_ESTIMATOR_STATUS: 15,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 17,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 19,
    mavlink.MAVLINK_MSG_ID_ORBIT_EXECUTION_STATUS: 21,
}

MAX_INTERVAL_US = 60_000_000


def phase_of(system_id: int) -> int:
    """The stream phase [ticks] of the autopilot with MAVLink ``system_id``: 0, 2, 4, … 18, then again (fleet
    neighbours' fast messages two ticks apart; the slow ones fall on odd ticks)."""
    return 2 * ((system_id - 1) % 10)


def spread_of(system_id: int) -> int:
    """How many ticks after vehicle 1's the autopilot with MAVLink ``system_id`` sends the messages with a slot of
    their own (:data:`SLOTS` > 0, the ones Python builds): 22 per vehicle, so that twenty vehicles fall on twenty
    different ticks of each 100 (0, 22, 44, 66, 88, 10, 32, …) and on ticks spread over the slower intervals too.
    Even: an odd slot stays off the vehicle's own fast ticks. Large real-time fleets miss fewer periods with it
    (docs/performance.md#spreading-a-fleets-work-over-the-ticks)."""
    return 22 * (system_id - 1)


class MessageStreams:
    """Per-message intervals, in ticks of ``period`` seconds (0 ticks = off): the fast messages and the positions at
    ``phase`` [ticks], each message with a slot of its own at ``spread`` + its slot [ticks]."""

    def __init__(self, period: float, fast_rate: float, phase: int = 0, spread: int = 0) -> None:
        self.period = period
        self.phases = {mid: (spread if SLOTS.get(mid, 0) else phase) + SLOTS.get(mid, 0)
                       for mid in (*FAST, *SLOW_RATES)}  # fmt: skip
        self.defaults: dict[int, int] = {mid: self._ticks(1.0 / fast_rate) for mid in FAST}
        self.defaults.update({mid: self._ticks(1.0 / hz) if hz else 0 for mid, hz in SLOW_RATES.items()})
        self.every = dict(self.defaults)
        self._rebuild()

    def _ticks(self, seconds: float) -> int:
        return max(1, round(seconds / self.period))

    def _rebuild(self) -> None:
        self._active = sorted((mid, n, self.phases[mid]) for mid, n in self.every.items() if n > 0)

    def supported(self, msg_id: int) -> bool:
        return msg_id in self.defaults

    def set_interval(self, msg_id: int, interval_us: float) -> str:
        """MAV_CMD_SET_MESSAGE_INTERVAL. Returns "" when done, else why not."""
        if not self.supported(msg_id):
            return f"Message interval: message id {msg_id:g} is not streamed"
        if interval_us == -1:
            self.every[msg_id] = 0
        elif interval_us == 0:
            self.every[msg_id] = self.defaults[msg_id]
        elif 0 < interval_us <= MAX_INTERVAL_US:
            self.every[msg_id] = self._ticks(interval_us * 1e-6)
        else:
            return f"Message interval {interval_us:g} us: expected -1, 0 or (0, {MAX_INTERVAL_US}]"
        self._rebuild()
        return ""

    def interval_us(self, msg_id: int) -> int:
        """MAV_CMD_GET_MESSAGE_INTERVAL's answer: µs, −1 when off, 0 when not streamed at all."""
        if not self.supported(msg_id):
            return 0
        n = self.every[msg_id]
        return -1 if n == 0 else round(n * self.period * 1e6)

    def due(self, tick: int, skip: Collection[int] = ()) -> list[int]:
        """The message ids to send at ``tick`` (but those in ``skip``)."""
        return [mid for mid, n, phase in self._active if (tick - phase) % n == 0 and mid not in skip]

    def next_due(self, tick: int, skip: Collection[int] = ()) -> int:
        """The first tick after ``tick`` at which a message (not in ``skip``) is due (so the loop need not ask every
        tick)."""
        return min((tick + 1 + (phase - tick - 1) % n for mid, n, phase in self._active if mid not in skip),
                   default=tick + 2**62)  # fmt: skip

    def schedule(self, mid: int) -> tuple[int, int]:
        """(interval, phase) [ticks] of message ``mid``; interval 0: off."""
        return self.every.get(mid, 0), self.phases.get(mid, 0)
