"""A link-impairment layer for real-time runs: loss, delay, jitter, duplication and reordering of the
datagrams between plant and autopilot, applied in the plant process to both directions.

Pure scheduling: :meth:`Impairment.schedule` says when (if ever, and how often) a datagram is delivered;
the plant's real-time loop keeps the queues and releases what is due. Duplicated and out-of-order
messages reach the receivers, which discard them by ``time_usec``.
"""

from __future__ import annotations

import argparse
import random
from dataclasses import dataclass

from quadsitl.cli_util import UsageError

KEYS = {"loss": "%", "delay": "s", "jitter": "s", "dup": "%", "reorder": "%"}


@dataclass(frozen=True)
class ImpairmentSpec:
    loss: float = 0.0  # [%] datagrams dropped
    delay: float = 0.0  # [s] added to every datagram
    jitter: float = 0.0  # [s] a further uniform 0..jitter
    dup: float = 0.0  # [%] datagrams delivered twice
    reorder: float = 0.0  # [%] datagrams held back one more delay + jitter + 2 ms, so later ones overtake

    @property
    def active(self) -> bool:
        return any((self.loss, self.delay, self.jitter, self.dup, self.reorder))


def parse_impairment(option: str, text: str) -> ImpairmentSpec:
    """'loss=5,jitter=0.002,...' → ImpairmentSpec, or a UsageError naming the option, key and value."""
    values: dict[str, float] = {}
    for item in filter(None, (x.strip() for x in text.split(","))):
        key, sep, raw = item.partition("=")
        if not sep or key not in KEYS:
            raise UsageError(f"{option} {item!r}: expected KEY=VALUE with KEY one of {', '.join(KEYS)}")
        try:
            value = float(raw)
        except ValueError:
            value = float("nan")
        limit = 100.0 if KEYS[key] == "%" else 1.0
        if not 0.0 <= value <= limit:
            raise UsageError(f"{option} {key}={raw}: expected a number in [0, {limit:g}] {KEYS[key]}")
        values[key] = value
    return ImpairmentSpec(**values)


class Impairment:
    def __init__(self, spec: ImpairmentSpec, seed: int = 0) -> None:
        self.spec = spec
        self.rng = random.Random(seed)
        self.dropped = self.duplicated = self.reordered = 0

    def schedule(self, now: float) -> list[float]:
        """Release times [s] for a datagram sent at ``now``: none (lost), one, or two (duplicated)."""
        s, rng = self.spec, self.rng
        if rng.random() * 100.0 < s.loss:
            self.dropped += 1
            return []
        copies = 1
        if rng.random() * 100.0 < s.dup:
            copies = 2
            self.duplicated += 1
        times = []
        for _ in range(copies):
            t = now + s.delay + rng.random() * s.jitter
            if rng.random() * 100.0 < s.reorder:
                t += s.delay + s.jitter + 0.002
                self.reordered += 1
            times.append(t)
        return times


def add_impair_argument(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--impair",
        metavar="SPEC",
        help="with --mode realtime: impair the plant link both ways, e.g. loss=5,jitter=0.002 "
        "(keys: loss %%, delay s, jitter s, dup %%, reorder %%)",
    )


def impairment_from(text: str | None, mode: str) -> Impairment | None:
    """The ``--impair`` option → an Impairment (None without one); a UsageError names what is wrong."""
    if not text:
        return None
    spec = parse_impairment("--impair", text)
    if mode != "realtime":
        raise UsageError("--impair: needs --mode realtime (lockstep waits for every answer)")
    return Impairment(spec)
