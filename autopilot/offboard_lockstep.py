"""Offboard lockstep: in a lockstep run the vehicle's clock waits for a ground station that falls behind it.

A lockstep run goes as fast as the plant and the autopilot answer each other, many times real time
(docs/performance.md#latest-figures). A ground station that streams a trajectory follows the vehicle's time through its
telemetry, so each setpoint is made for a moment already past, by the ground station's latency times that speed:
milliseconds of wall time are tenths of a second of flight, and one stall of a busy machine can be seconds. The
reference flown then depends on the machine's load.

With ``quadsitl autopilot --offboard-lockstep S`` (``quadsitl fly`` uses it) the autopilot answers no plant tick
more than S simulated seconds after the moment its newest offboard setpoint was made for: the setpoint's
``time_boot_ms``, which quadsitl's ground station stamps from the vehicle's own clock (the tick of the newest
telemetry it has seen, as the ATTITUDE stream's ``time_boot_ms``). So the reference flown lags the trajectory by
at most S on any machine. The clock waits for a setpoint as long as the ground station is there: until it has not
been heard (its heartbeat) for ``hold_max`` of wall time, the autopilot's datalink timeout (COM_DL_LOSS_T, 10 s), or
:data:`HOLD_MAX` when it was never heard. A ground station descheduled for seconds by a busy machine (or stopped
with SIGSTOP) holds the simulated clock the whole time, so the flight is the same as if it had never stopped; one that
has gone is then the datalink-loss and setpoint-loss failsafes' business, as without the option.

PX4's lockstep never waits for an offboard API, and a client that stamps ``time_boot_ms`` from its own clock
(MAVSDK does) would make every setpoint wait ``hold_max``: so the option is off by default, for ground
stations that stamp with the vehicle's time.

A ground station may also send its setpoints ahead of the vehicle's clock (``quadsitl gcs --setpoints-ahead``, as
``quadsitl fly`` runs it with a lead of 0): a setpoint made for a later tick than the next is held
(:meth:`OffboardLockstep.hold`) and flown from exactly that tick (:meth:`OffboardLockstep.due`), and the clock
answers tick k only once a setpoint made for k + 2 or later has come, so every setpoint for the ticks up to k + 1 is
in (the datagrams of one ground station arrive in order; an attitude setpoint is a pair of messages made for one
moment). The reference flown at each tick is then the ground station's for that tick, whatever the machine's
timing: a run flies to the byte. A setpoint made for a moment more than :data:`HOLD_AHEAD` ahead (a foreign clock's
stamp) is flown as it comes.

Pure and I/O-free: the autopilot's shell calls :meth:`OffboardLockstep.stamp` for each offboard setpoint and
:meth:`OffboardLockstep.must_wait` after each tick it would answer, and while it waits.
"""

from __future__ import annotations

HOLD_MAX = 0.25  # [s] wall: the longest the clock waits for one setpoint from a ground station never heard
HOLD_AHEAD = 2.0  # [s] simulated: a setpoint made for at most this far ahead of the vehicle's clock is held until then
NO_WAIT = 2**63 - 1  # free_until: no tick waits


class OffboardLockstep:
    """When the answer to a plant tick must wait for a newer offboard setpoint.

    ``lead`` [s, simulated]: how far the vehicle's clock may run past the moment the newest setpoint was made for;
    ``period`` [s]: the control period (a tick); ``hold_max`` [s, wall]: how long after the ground station was last
    heard (or, never heard, after the wait began) the clock stops waiting for it (the shell sets it to its datalink
    timeout)."""

    def __init__(self, lead: float, period: float, hold_max: float = HOLD_MAX) -> None:
        self.period = period
        self.lead_ticks = round(lead / period)
        self.hold_max = hold_max
        self.newest = -1  # the tick the newest setpoint was made for (−1: none stamped yet)
        self.held: list[tuple[int, int, object]] = []  # (tick, arrival order, setpoint) made for a later tick
        self.order = 0
        self.gave_up = -1  # the newest tick when a wait last ran out: no further wait until a newer setpoint
        self.since: float | None = None  # [s] wall: when the current wait began
        self.waits = 0  # how many times the clock waited
        self.gave_up_count = 0  # of which ran out of HOLD_MAX
        self.waited = 0.0  # [s] wall: the time spent waiting, in all

    def stamp(self, time_boot_ms: int) -> None:
        """A setpoint made for the vehicle's time ``time_boot_ms`` [ms] (its tick × period)."""
        self.newest = max(self.newest, self.tick_of(time_boot_ms))

    def tick_of(self, time_boot_ms: int) -> int:
        """The tick a setpoint stamped ``time_boot_ms`` [ms] was made for."""
        return round(time_boot_ms / 1000.0 / self.period)

    def hold(self, tick: int, now_tick: int, setpoint: object) -> bool:
        """A setpoint made for ``tick``, arrived after ``now_tick`` was flown: True when it is held until then (made
        for a tick after the next one, and at most HOLD_AHEAD ahead), False when it is to be flown now."""
        if not now_tick + 1 < tick <= now_tick + round(HOLD_AHEAD / self.period):
            return False
        self.held.append((tick, self.order, setpoint))
        self.order += 1
        self.held.sort(key=lambda h: h[:2])
        return True

    def due(self, next_tick: int) -> list:
        """The held setpoints to fly from ``next_tick`` on (made for it or before), in the order they were made."""
        n = 0
        while n < len(self.held) and self.held[n][0] <= next_tick:
            n += 1
        out, self.held = [h[2] for h in self.held[:n]], self.held[n:]
        return out

    def next_due(self) -> int:
        """The tick the first held setpoint is made for (NO_WAIT: none held)."""
        return self.held[0][0] if self.held else NO_WAIT

    def must_wait(self, tick: int, flying_offboard: bool, wall: float, heard: float | None = None) -> bool:
        """True while the answer to ``tick`` must wait: flying offboard, no setpoint yet made for ``tick`` + 2 −
        ``lead`` or later (one made for a later tick completes the ones before it), and the ground station heard
        within ``hold_max`` [s] of ``wall`` time (``heard``: when it last was; None: never, the wait's start
        counts)."""
        behind = flying_offboard and self.newest >= 0 and tick + 2 - self.newest > self.lead_ticks
        if not behind or self.newest == self.gave_up:
            self._end(wall)
            return False
        if self.since is None:
            self.since = wall
            self.waits += 1
            return True
        last = self.since if heard is None else max(heard, self.since)
        if wall - last >= self.hold_max:
            self.gave_up = self.newest
            self.gave_up_count += 1
            self._end(wall)
            return False
        return True

    def free_until(self, flying_offboard: bool) -> int:
        """The last tick whose answer need not ask :meth:`must_wait` (it would answer False and change nothing):
        so a compiled loop answers up to it alone (:mod:`autopilot.plant_loop`). −1 while a wait is under way;
        NO_WAIT when no tick will wait until a newer setpoint comes (or the vehicle leaves or enters offboard)."""
        if self.since is not None:
            return -1
        if not flying_offboard or self.newest < 0 or self.newest == self.gave_up:
            return NO_WAIT
        return self.newest + self.lead_ticks - 2

    def _end(self, wall: float) -> None:
        if self.since is not None:
            self.waited += wall - self.since
            self.since = None
