"""The autopilot's plant link: its socket, the datagram buffer the compiled tick reads in place and the answer it
writes, the plant the link is locked to, and the compiled loop that serves it (:mod:`autopilot.plant_loop`), polling
while the plant answers fast, with patience where nothing paces the plant (measured from the ticks' pace) and
without where something does (real time, ``--speed`` below 2)."""

from __future__ import annotations

import os
import select
import socket
import time

import numpy as np

from autopilot import plant_loop
from autopilot import tick as kernel
from quadsitl import codec, fastio, wire
from quadsitl.process_util import HOT_AFTER, PATIENCE, PaceGauge, SpinThenBlock, bind_udp

PLANT_LOST_AFTER = 0.5  # [s] wall without a vehicle state: the plant link is lost (failsafe)
PLANT_SILENCE = 1.0  # [s] wall: after this long without the locked plant, another plant may take the link
PLANT_HOLDING = 0.005  # [s] wall: a plant quiet this long may be holding its clock (Autopilot.answer_armed)
STRANGER, SAME, NEW = 0, 1, 2  # what admit() says of a datagram's sender
NO_PEER = np.zeros(fastio.SOCKADDR_IN, dtype=np.uint8)  # no plant locked yet: no sender's address matches it


class PlantLink:
    """The plant link of one autopilot, bound to ``listen`` (``--plant-listen``), for a control ``period`` [s]."""

    def __init__(self, listen: str, period: float, system: int) -> None:
        self.sock = bind_udp("--plant-listen", listen)
        self.unlocked = False  # served without Python's lock (plant_loop.serve_unlocked): a host's vehicles, in threads
        self.rx = bytearray(65535)  # the datagram, read in place by the compiled decoder
        self.rx_array = np.frombuffer(self.rx, dtype=np.uint8)
        self.tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)  # the answer, written by the compiled tick
        self.tx_view = memoryview(self.tx)  # type: ignore[arg-type]
        self.mav = wire.link(system, wire.AUTOPILOT_COMPONENT_ID)  # the fallback parser (plant_messages)
        self.peer: tuple[str, int] | None = None  # the plant the link is locked to
        self.heard = 0.0  # wall time its last datagram arrived
        self.lost = False
        self.wait = SpinThenBlock(self.sock.recvfrom_into, self.rx, patience=PATIENCE)
        self.pace = PaceGauge(period)
        # Served in compiled code once a plant is heard on an IPv4 socket:
        self.fast = fastio.compiled_loops() and self.sock.family == socket.AF_INET
        self.address: np.ndarray | None = None  # the locked plant's sockaddr (fast only)
        self.sender = np.zeros(fastio.SOCKADDR_IN, dtype=np.uint8)  # where a datagram came from (fast only)
        self.sender_len = np.zeros(1, dtype=np.int32)
        self.stats = np.zeros(plant_loop.STATS_SIZE, dtype=np.int64)

    def admit(self, sender: tuple[str, int], wall: float) -> int:
        """A datagram from ``sender`` at ``wall``: the link is locked to the first plant that talks to it; another
        sender is a STRANGER, until the locked plant has been silent for PLANT_SILENCE (then a restarted plant, on a
        new port, takes over: NEW)."""
        if sender == self.peer:
            self.heard = wall
            return SAME
        if self.peer is not None and wall - self.heard < PLANT_SILENCE:
            return STRANGER
        self.peer, self.heard = sender, wall
        self.address = fastio.sockaddr(sender) if self.fast else None
        return NEW

    def answer(self, io: np.ndarray, to: tuple[str, int]) -> None:
        """The answer the tick wrote (io[TX_LEN] bytes) to ``to``."""
        self.sock.sendto(self.tx_view[: io[kernel.TX_LEN]], to)

    def silent(self, wall: float) -> bool:
        """The locked plant has said nothing for PLANT_LOST_AFTER (and was not already lost), and nothing waits to be
        read: a loop held up elsewhere (a telemetry put that waits for a subscriber's room) has a plant that spoke."""
        if self.peer is None or self.lost or wall - self.heard <= PLANT_LOST_AFTER:
            return False
        return not select.select([self.sock], [], [], 0)[0]

    def holding(self) -> bool:
        """The plant has been quiet for PLANT_HOLDING: it may be holding its clock until the vehicle arms."""
        return time.monotonic() - self.heard >= PLANT_HOLDING

    def serve(self, io: np.ndarray, tick_args: tuple, deadline: float, limit: int, destinations: np.ndarray,
              ground_fds: np.ndarray, next_poll: float, ground_every: float) -> tuple:  # fmt: skip
        """Serve the link in compiled code until Python has something to do (a tick whose flags need it, a stranger's
        datagram, ``deadline`` [s wall], a datagram on a ground-station socket from ``next_poll`` on, every
        ``ground_every``, a quiet plant) → (status, nbytes, flags, when the ground sockets are next asked [s wall], the
        wall time [s] it handed back)."""
        wait, stats = self.wait, self.stats
        stats[:] = 0
        stats[plant_loop.SHORT] = wait.short
        stats[plant_loop.NEXT_GROUND] = int(next_poll * 1e9)
        polling = wait.polling()
        serve = plant_loop.serve_unlocked if self.unlocked else plant_loop.serve
        status, nbytes, flags = serve(
            self.sock.fileno(), self.rx_array, self.sender, self.sender_len, self.address, self.tx, io, tick_args,
            int(deadline * 1e9), polling, int(wait.budget * 1e9), int(wait.patience * 1e9), HOT_AFTER, limit, stats,
            destinations, ground_fds, int(ground_every * 1e9),
        )  # fmt: skip
        if status == plant_loop.SENT or status == plant_loop.DUE:
            # Python's turn, the answer already out: first the fleet-mates waiting for this core answer their ticks.
            # sched_yield puts this process behind them (under SCHED_FIFO, at the end of its priority's queue, where
            # nothing else would take the core from it until it blocks); docs/performance.md, "Yielding the core".
            os.sched_yield()
        wall = self.after_loop(status)
        wait.tally(int(stats[plant_loop.POLLED]), int(stats[plant_loop.LATE]), polling and status == plant_loop.QUIET,
                   int(stats[plant_loop.BLOCKED]), int(stats[plant_loop.SHORT]))  # fmt: skip
        pace = self.pace.update(int(io[kernel.TICK]), wall)
        if pace is not None:
            wait.be_patient(PaceGauge.patience(pace))
        return status, nbytes, flags, stats[plant_loop.NEXT_GROUND] * 1e-9, wall

    def group_entry(self, io: np.ndarray, tick_args: tuple, destinations: tuple, ground_fds: np.ndarray) -> tuple:
        """This link's part of :func:`plant_loop.serve_group`'s vehicles (:func:`plant_loop.group_entry`); the locked
        plant's address, or none yet (all zero: no sender matches it)."""
        peer = self.address if self.address is not None else NO_PEER
        return plant_loop.group_entry(self.sock.fileno(), self.rx_array, self.sender, self.sender_len, peer, self.tx,
                                      io, tick_args, self.stats, destinations, ground_fds)  # fmt: skip

    def after_loop(self, status: int) -> float:
        """A compiled loop (:func:`plant_loop.serve`, :func:`plant_loop.serve_group`) gave this link back to Python
        with ``status``: the plant heard, if the loop answered it since the last time → the wall time [s]."""
        wall = time.monotonic()
        if self.stats[plant_loop.ANSWERED] or status == plant_loop.TICKED:
            self.heard = wall
        return wall

    def close(self) -> None:
        self.sock.close()
