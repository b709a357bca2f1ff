"""The ground-station links: each bound socket with its fixed remote, learned peers and message intervals
(:class:`GcsLink`), and what they share (:class:`GroundLinks`): the MAVLink codec (signed when a key is given; one
sequence with the frames the compiled tick builds, kept in the tick's bookkeeping ``io[GCS_SEQ]``) and the reading
of what waits on the sockets, within a time budget."""

from __future__ import annotations

import socket
import sys
import time
from collections.abc import Iterator

import numpy as np

from autopilot import tick as kernel
from autopilot.records import Counters
from autopilot.streams import MessageStreams
from quadsitl import codec, wire

mavlink = wire.mavlink
PEER_TIMEOUT = 30.0  # [s] wall: stop streaming to a peer that has been silent this long


class GcsLink:
    """One ground-station socket: a bound local address, an optional fixed remote, learned peers, and
    its own message intervals (SET_MESSAGE_INTERVAL applies to the link it arrives on, as in PX4)."""

    def __init__(self, name: str, sock: socket.socket, remote: tuple[str, int] | None, streams: MessageStreams,
                 label: str = "autopilot") -> None:  # fmt: skip
        self.name, self.sock, self.remote, self.streams = name, sock, remote, streams
        self.label = label  # who says so on stderr: "autopilot v2"
        self.peers: dict[tuple[str, int], float] = {}  # address → wall time last heard
        self.send_errors = 0  # datagrams the OS refused to send (a peer gone, a remote this socket cannot reach)
        self._told: set[tuple[tuple[str, int], int | None]] = set()  # (destination, errno) already reported

    def send(self, buf: bytes, to: list[tuple[str, int]] | None = None) -> bool:
        """``buf`` to every destination (or those in ``to``) → False when a learned peer was dropped. A send the OS
        refuses drops a learned peer (it is heard again if it comes back) and is counted; each destination's first
        failure of a kind is one line on stderr, so a remote this link cannot reach (a loopback-bound socket and
        another host's address: EINVAL) is never silent, and a flight controller never stops for it."""
        peers = len(self.peers)
        for peer in self.destinations() if to is None else to:
            try:
                self.sock.sendto(buf, peer)
            except OSError as exc:
                self.peers.pop(peer, None)
                self.send_errors += 1
                if (peer, exc.errno) not in self._told:
                    self._told.add((peer, exc.errno))
                    host, port = self.sock.getsockname()[:2]
                    why = exc.strerror or exc
                    print(f"{self.label}: {self.name} link: cannot send to {peer[0]}:{peer[1]} from {host}:{port}: "
                          f"{why} (said once for this destination and error)", file=sys.stderr)  # fmt: skip
        return len(self.peers) == peers

    def destinations(self) -> list[tuple[str, int]]:
        out = list(self.peers)
        if self.remote is not None and self.remote not in self.peers:
            out.append(self.remote)
        return out

    def forget_silent(self, now: float) -> bool:
        """Forget the peers not heard for PEER_TIMEOUT → whether any was."""
        silent = [peer for peer, seen in self.peers.items() if now - seen > PEER_TIMEOUT]
        for peer in silent:
            del self.peers[peer]
        return bool(silent)


class GroundLinks:
    """The ground-station links (``gcs``, ``api``) and their MAVLink codec: whatever goes out goes to every link's
    destinations; whatever comes in is read here, counted when it is not MAVLink."""

    def __init__(self, links: list[GcsLink], system: int, component: int, signing_key: bytes | None,
                 io: np.ndarray, counters: Counters) -> None:  # fmt: skip
        self.links, self.system, self.component = links, system, component
        self.signing_key, self.io, self.counters = signing_key, io, counters
        self.mav = self.codec()

    def __iter__(self) -> Iterator[GcsLink]:
        return iter(self.links)

    def __getitem__(self, i: int) -> GcsLink:
        return self.links[i]

    def codec(self, old: mavlink.MAVLink | None = None) -> mavlink.MAVLink:
        """A fresh parser/packer; with a key, signed (and keeping the old one's signing state, so replay protection
        and the refusal count survive a reset)."""
        mav = wire.link(self.system, self.component)
        if self.signing_key is not None:
            wire.enable_signing(mav, self.signing_key)
            if old is not None:
                mav.signing = old.signing
        return mav

    def pack(self, msg) -> bytes:
        """``msg`` framed, in one sequence with the frames the compiled tick builds."""
        self.mav.seq = int(self.io[kernel.GCS_SEQ])
        buf = codec.pack(msg, self.mav)
        self.io[kernel.GCS_SEQ] = self.mav.seq
        return buf

    def send(self, msg) -> None:
        """``msg`` to every link's destinations."""
        buf = self.pack(msg)
        for link in self.links:
            link.send(buf)

    def read(self, budget: float, say_once) -> Iterator[tuple[object, GcsLink, tuple[str, int]]]:
        """The messages waiting on the sockets, with the link and the sender of each, for up to ``budget`` seconds
        of work: a flood of datagrams (hostile or not) waits in the socket buffers, or overflows them, while the
        plant link is serviced between reads; it never starves the control loop. Datagrams that are not MAVLink
        are counted; a message refused for its signature is said (``say_once(topic, text)``)."""
        deadline = time.perf_counter() + budget
        for link in self.links:
            while time.perf_counter() < deadline:
                try:
                    data, sender = link.sock.recvfrom(65535)
                except (BlockingIOError, InterruptedError):
                    break
                except OSError:
                    break  # e.g. an ICMP error reported on the socket: nothing to read
                refused_before = wire.signing_refusals(self.mav)
                try:
                    msgs = self.mav.parse_buffer(data) or []
                except Exception:  # pymavlink raises MAVError, and others on hostile bytes: never crash
                    self.counters.comm += 1
                    self.mav = self.codec(self.mav)  # a parser in an unknown state: start over
                    continue
                if wire.signing_refusals(self.mav) > refused_before:
                    say_once("signing", f"Unsigned or badly signed message refused from {sender[0]} "
                                        f"({wire.signing_refusals(self.mav)} so far)")  # fmt: skip
                for m in msgs:
                    if m.get_type() == "BAD_DATA":
                        self.counters.comm += 1
                        continue
                    yield m, link, sender

    def close(self) -> None:
        for link in self.links:
            link.sock.close()
