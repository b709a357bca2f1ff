"""The plant's end of its UDP link to one autopilot (:class:`PlantLink`): the state (or its measurements) out, the
actuator commands in, both encoded and decoded in place by the compiled codec, and the account of the autopilot's
answers (heard, lost, late) that the lockstep and real-time clocks keep (:mod:`sitl.lockstep`, :mod:`sitl.realtime`).

Impaired links (``--impair``, real time only) send and receive through :class:`PlantLink`'s queues.
"""

from __future__ import annotations

import contextlib
import heapq
import math
import socket
import sys
import time

import numpy as np

from quadsitl import codec, hil, wire
from quadsitl.process_util import SpinThenBlock, set_receive_timeout, wait_readable
from sitl import realtime_loop, sensors, tick
from sitl.impair import Impairment
from sitl.plant import Plant

HIL_ACTUATOR_CONTROLS = wire.mavlink.MAVLINK_MSG_ID_HIL_ACTUATOR_CONTROLS
COMMAND_LONG = wire.mavlink.MAVLINK_MSG_ID_COMMAND_LONG
AUTOPILOT_LOST_AFTER = 0.5  # [s] wall without an actuator message: the autopilot is lost
LOST_AFTER_NS = round(AUTOPILOT_LOST_AFTER * 1e9)


class PlantLink:
    """The plant's end of the UDP link: send states, receive actuator commands. The two per-tick messages
    are encoded and decoded in place by the compiled codec (:mod:`quadsitl.codec`, :mod:`sitl.tick`)."""

    def __init__(
        self,
        sock: socket.socket,
        autopilot: tuple[str, int],
        max_thrust: float,
        period: float,
        impairment: Impairment | None = None,
        sensing: bool = False,
        name: str = "",
    ):
        self.sock = sock  # bound (process_util.bind_udp)
        self.who = f"{name}'s autopilot" if name else "autopilot"  # in messages (a fleet's name the vehicle)
        self.rx = bytearray(65535)
        self.rx_array = np.frombuffer(self.rx, dtype=np.uint8)
        self.tx = np.zeros(max(codec.FRAME_MAX, hil.DATAGRAM_MAX), dtype=np.uint8)
        self.tx_view = memoryview(self.tx)  # type: ignore[arg-type]
        self.io = np.zeros(tick.IO_SIZE, dtype=np.int64)  # sequence, frame length, last stamp used, refusals
        self.io[tick.LAST_USEC] = -1
        self.io[tick.SYSTEM], self.io[tick.COMPONENT] = wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID
        self.io[tick.SENSING] = sensing
        self.io[tick.HOLD_TICK] = -1  # lockstep: the tick at which the clock holds until the autopilot arms
        self.received = np.zeros(4)  # the commanded forces [N] of the last actuator message decoded
        self.wait = SpinThenBlock(sock.recv_into, self.rx)  # lockstep's receive: polls while the autopilot answers fast
        self.sock.connect(autopilot)  # the kernel drops datagrams from anyone but the autopilot
        self.mav = wire.link(wire.PLANT_SYSTEM_ID, wire.PLANT_COMPONENT_ID)
        self.max_thrust = max_thrust
        self.period = period
        self.timeout = -1.0
        # answered and late periods, when the autopilot was first and last heard, whether it is lost: one account
        # for the Python loops and the compiled real-time one (sitl.realtime_loop)
        self.rt = np.zeros(realtime_loop.RT_SIZE, dtype=np.int64)
        self.impairment = impairment  # real-time runs only: both directions go through its queues
        self.outbox: list[tuple[float, int, bytes]] = []  # (release time, order, datagram), a heap
        self.inbox: list[tuple[float, int, bytes]] = []
        self.order = 0
        # the plant's sensors (failures are injected in their schedule, read when injected: a fleet's arrays
        # (sitl.fleet_arrays) replace it with a row of theirs)
        self.sensors: sensors.Sensors | None = None

    @property
    def last_heard(self) -> float | None:
        """When the autopilot was last heard [s, time.monotonic] (None: not yet)."""
        ns = self.rt[realtime_loop.LAST_NS]
        return None if ns == 0 else ns * 1e-9

    @last_heard.setter
    def last_heard(self, wall: float) -> None:
        self.rt[realtime_loop.LAST_NS] = round(wall * 1e9)

    @property
    def first_heard(self) -> float | None:
        """... and first: the run's pace counts from its first answer."""
        ns = self.rt[realtime_loop.FIRST_NS]
        return None if ns == 0 else ns * 1e-9

    @property
    def lost(self) -> bool:
        """Whether the autopilot is lost: silent for longer than AUTOPILOT_LOST_AFTER."""
        return bool(self.rt[realtime_loop.LOST])

    @property
    def discarded(self) -> int:
        """Actuator messages discarded: stale, duplicates, or (lockstep) from the future."""
        return int(self.io[tick.DISCARDED])

    @property
    def corrupt(self) -> int:
        """Datagrams refused: corrupt frames, non-finite forces."""
        return int(self.io[tick.CORRUPT])

    def encode(self, k: int, plant: Plant) -> None:
        """Tick ``k``'s datagram (the state, or its measurements), into tx."""
        tick.encode_tick(self.tx, self.io, plant.x, plant.out, plant.air, plant.sens, k, self.period)

    def send(self, frame: bytes | None = None) -> None:
        """Send the state frame in tx (or ``frame``, one sent before)."""
        frame = self.tx_view[: self.io[tick.TX_LEN]] if frame is None else frame
        if self.impairment is not None:
            self._queue(self.outbox, bytes(frame))
            return
        with contextlib.suppress(ConnectionRefusedError):  # no autopilot yet (an ICMP error): free-wheel
            self.sock.send(frame)

    def send_state(self, k: int, plant: Plant) -> None:
        self.encode(k, plant)
        self.send()

    def _queue(self, queue: list, datagram: bytes) -> None:
        for t in self.impairment.schedule(time.monotonic()):
            self.order += 1
            heapq.heappush(queue, (t, self.order, datagram))

    def next_event(self) -> float:
        """When the next impaired datagram is due [s, monotonic] (inf when none waits)."""
        return min(self.outbox[0][0] if self.outbox else math.inf, self.inbox[0][0] if self.inbox else math.inf)

    def heard(self) -> None:
        """An actuator message was used: the autopilot is there (:func:`sitl.realtime_loop.heard`)."""
        if realtime_loop.heard(self.rt, time.monotonic_ns()) == realtime_loop.BACK_NOW:
            self.say_back()

    def say_back(self) -> None:
        print(f"plant: {self.who} back; following its commands", file=sys.stderr, flush=True)

    def say_lost(self, action: str) -> None:
        print(f"plant: {self.who} lost (no answer for {AUTOPILOT_LOST_AFTER:g} s); {action}", file=sys.stderr,
              flush=True)  # fmt: skip

    def check_lost(self, action: str) -> bool:
        """True while the autopilot has been silent for AUTOPILOT_LOST_AFTER (said once per loss:
        :func:`sitl.realtime_loop.lost_clock`)."""
        lost = realtime_loop.lost_clock(self.rt, time.monotonic_ns(), LOST_AFTER_NS)
        if lost == realtime_loop.LOST_NOW:
            self.say_lost(action)
        return lost != 0

    def receive(self, timeout: float | None) -> int:
        """One datagram into rx: its length, or −1 when none came within ``timeout`` seconds."""
        if timeout != self.timeout:
            set_receive_timeout(self.sock, timeout)
            self.timeout = timeout
        try:
            return self.wait()
        except ConnectionRefusedError:
            # The ICMP error of a send to a port nobody listens on (the autopilot gone, or not started yet) ends the
            # receive after it at once: wait on for an answer, or a free-wheeling plant sends its tick again (to every
            # vehicle of a fleet) as fast as a core allows, not every FREEWHEEL_PERIOD (sitl.lockstep).
            with contextlib.suppress(BlockingIOError, InterruptedError, ConnectionRefusedError):
                return self.wait()
            return -1
        except (BlockingIOError, InterruptedError):
            return -1

    def decode(self, nbytes: int) -> int:
        """The stamp of the actuator message in rx[:nbytes] (its forces in ``self.received``); −1 when there
        is none (corrupt and non-finite ones counted)."""
        t = codec.decode_actuators(self.rx_array, nbytes, self.received, self.max_thrust)
        if t == codec.NOT_THIS_FRAME:
            return self._decode_slowly(nbytes)
        if t < 0:
            self.io[tick.CORRUPT] += 1
        return t

    def _decode_slowly(self, nbytes: int) -> int:
        """What pymavlink finds in a datagram the compiled decoder does not take (several messages, signed):
        the newest finite HIL_ACTUATOR_CONTROLS, its forces in ``self.received``; −1 when there is none."""
        try:
            msgs = self.mav.parse_buffer(bytes(self.rx[:nbytes])) or []
        except wire.mavlink.MAVError:
            self.io[tick.CORRUPT] += 1
            return -1
        for m in msgs:
            if m.get_msgId() == COMMAND_LONG and m.command == wire.mavlink.MAV_CMD_INJECT_FAILURE:
                self.inject_failure(m)
        msgs = [m for m in msgs if m.get_msgId() == HIL_ACTUATOR_CONTROLS]
        best = -1
        for m in msgs:
            if not all(map(math.isfinite, m.controls[:4])):
                self.io[tick.CORRUPT] += 1  # never integrate a non-finite force
            elif m.time_usec > best:
                best = m.time_usec
                self.received[:] = wire.forces_from_message(m, self.max_thrust)
                self.io[tick.ANSWER_ARMED] = 1 if m.mode & codec.SAFETY_ARMED else 0
        return best

    def inject_failure(self, m) -> None:
        """A sensor failure the autopilot passes on (MAV_CMD_INJECT_FAILURE, which it checked): made physical in the
        sensors (:func:`sitl.sensors.inject_failure`), from the next tick on; said on stderr."""
        unit, kind = round(m.param1), round(m.param2)
        if self.sensors is not None and sensors.inject_failure(self.sensors.clock, unit, kind):
            print(f"plant: failure injected: sensor unit {unit}, type {kind}", file=sys.stderr, flush=True)

    def apply(self, plant: Plant, t: int) -> bool:
        """Real time: make the actuator message stamped ``t`` (forces in ``self.received``) the command,
        unless it is older than the last used (:func:`sitl.realtime_loop.apply`)."""
        if t < 0:
            return False
        r = realtime_loop.apply(t, self.received, self.io, self.rt, plant.commanded, time.monotonic_ns())
        if r == realtime_loop.BACK_NOW:
            self.say_back()
        return r >= 0

    def end_period(self, want: int, plant: Plant, zero_on_loss: bool, action: str) -> None:
        """Real time, the period's answers taken (:meth:`apply`): counted, the lost clock, one step
        (:func:`sitl.realtime_loop.end_period`)."""
        flags = realtime_loop.end_period(self.io, self.rt, plant.commanded, want, time.monotonic_ns(), LOST_AFTER_NS,
                                         zero_on_loss, *self.step_args(plant))  # fmt: skip
        if flags & realtime_loop.LOST_NOW:
            self.say_lost(action)
        plant.time += plant.period

    @staticmethod
    def step_args(plant: Plant) -> tuple:
        """The arguments of :func:`sitl.plant.step_work` for ``plant``."""
        return plant.work, plant.params, plant.air_rng, plant.period, plant.substeps, plant.method

    def receive_within(self, seconds: float, plant: Plant) -> None:
        """Real time: apply every actuator message that arrives within ``seconds`` (microsecond precision:
        select); SO_RCVTIMEO counts in kernel ticks (4–10 ms) and Python's socket timeout in whole
        milliseconds, both too coarse for a 1 kHz schedule."""
        if self.impairment is None:
            if wait_readable(self.sock, seconds):
                nbytes = self.receive(None)
                if nbytes >= 0:
                    self.apply(plant, self.decode(nbytes))
            return
        self._release(plant)
        wait = min(seconds, max(0.0, self.next_event() - time.monotonic()))
        if wait_readable(self.sock, wait):
            with contextlib.suppress(BlockingIOError, InterruptedError, ConnectionRefusedError):
                self._queue(self.inbox, self.sock.recv(65535))
        self._release(plant)

    def drain(self, plant: Plant) -> None:
        """Real time, unimpaired: apply every actuator message waiting in the socket, without waiting (the newest
        stamp wins; older ones are discarded as stale)."""
        while True:
            try:
                nbytes = self.sock.recv_into(self.rx, 0, socket.MSG_DONTWAIT)
            except (BlockingIOError, InterruptedError, ConnectionRefusedError):
                return
            self.apply(plant, self.decode(nbytes))

    def _release(self, plant: Plant) -> None:
        """Send the due outgoing datagrams; apply the due incoming ones."""
        now = time.monotonic()
        while self.outbox and self.outbox[0][0] <= now:
            with contextlib.suppress(ConnectionRefusedError):
                self.sock.send(heapq.heappop(self.outbox)[2])
        while self.inbox and self.inbox[0][0] <= now:
            datagram = heapq.heappop(self.inbox)[2]
            self.rx[: len(datagram)] = datagram
            self.apply(plant, self.decode(len(datagram)))

    def announce(self, severity: int, text: str) -> None:
        """``text`` as STATUSTEXT to the autopilot, all its chunks in one datagram, at once (no impairment: the
        plant is about to end); nobody listening is no error."""
        frames = b"".join(codec.pack(m, self.mav) for m in wire.statustext(severity, text, 1))
        with contextlib.suppress(OSError):
            self.sock.send(frames)

    def close(self) -> None:
        self.sock.close()
