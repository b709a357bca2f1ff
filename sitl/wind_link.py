"""The plant's Zenoh input: the wind changed while it flies (``quadsitl up``), a thin shell around
:func:`quadsitl.config.wind_change` and :mod:`sitl.wind`.

- ``quadsitl/<vehicle>/wind`` (in): a JSON object with any of the [wind] keys (docs/presets.md), e.g.
  ``{"speed_m_s": 5, "from_deg": 270}``; the keys not given keep their value. In a change, ``gust_start_s``
  counts from when the plant takes it (0: now), not from lift-off.
- ``quadsitl/<vehicle>/wind/now`` (out): the wind in effect, every key, as JSON, once when the plant starts and
  after each change; a refused change leaves the wind as it was and is answered with ``"refused"``: the reason,
  naming the key, the value and what is allowed (also on the plant's stderr).

A change is checked on Zenoh's thread and taken by the plant's loop between two ticks (:meth:`WindLink.take`),
so a tick never sees half of one. In lockstep a change lands at the tick the loop has reached when it arrives:
the run stays deterministic only without changes.
"""

from __future__ import annotations

import json
import sys
from collections import deque
from dataclasses import asdict, replace
from typing import Any

from quadsitl import telemetry
from quadsitl.config import ConfigError, WindParams, wind_change
from sitl.noise import seed_streams
from sitl.plant import Plant
from sitl.wind import AIR_PARAMS, AIR_STATE, CLOCK, GUST_START, wind_params

GUST_KEYS = {"gust_m_s", "gust_rise_s", "gust_start_s", "gust_from_deg"}


def change_wind(plant: Plant, wind: WindParams, values: dict[str, Any], gust_from: float) -> tuple[WindParams, float]:
    """Change ``plant``'s wind, now ``wind`` (whose gust counts from ``gust_from`` [s on the wind's clock]), by the
    checked ``values`` (:func:`quadsitl.config.wind_change`), between two ticks: (the wind now, when its gust
    counts from). A change of the gust counts from now; a new seed restarts the turbulence's random stream; the
    turbulence's filters and the wind's clock go on."""
    wind = replace(wind, **values)
    if GUST_KEYS & set(values):
        gust_from = max(plant.air[AIR_STATE + CLOCK], 0.0) * plant.period
    p = wind_params(wind)
    p[GUST_START] += gust_from
    plant.air[AIR_PARAMS:] = p
    if "seed" in values:
        plant.air_rng[:] = seed_streams(wind.seed, 1)
    return wind, gust_from


class WindLink:
    """Wind changes for one vehicle's plant (whose preset's wind is ``wind``), on a Zenoh ``session`` that a
    process simulating several vehicles shares among them."""

    def __init__(self, session: Any, vehicle: str, wind: WindParams) -> None:
        self.wind = wind
        self.gust_from = 0.0  # [s on the wind's clock]: when the wind in effect's gust_start_s counts from
        self.inbox: deque[dict[str, Any]] = deque()  # checked changes, from Zenoh's thread to the plant's loop
        self.taken = self.refused = 0
        self.session = session  # a Zenoh session, the process's (it closes it)
        prefix = f"{telemetry.PREFIX}/{vehicle}/wind"
        self.publisher = self.session.declare_publisher(f"{prefix}/now")
        self.subscriber = self.session.declare_subscriber(prefix, self._on_sample)
        self._say()

    def _on_sample(self, sample: Any) -> None:
        try:
            self.inbox.append(wind_change(sample.payload.to_bytes()))
        except ConfigError as exc:  # the wind stays as it was
            self.refused += 1
            print(f"plant: wind change refused: {exc}", file=sys.stderr, flush=True)
            self._say(refused=str(exc))

    def _say(self, refused: str | None = None) -> None:
        now: dict[str, Any] = asdict(self.wind)
        if refused is not None:
            now["refused"] = refused
        self.publisher.put(json.dumps(now), encoding="application/json")

    def take(self, plant: Plant) -> None:
        """Apply the changes that arrived to ``plant``'s wind, between two ticks (call it when ``inbox``)."""
        while self.inbox:
            self.wind, self.gust_from = change_wind(plant, self.wind, self.inbox.popleft(), self.gust_from)
            self.taken += 1
            self._say()

    def close(self) -> None:
        """Undeclare the subscriber and the publisher (the session stays the caller's)."""
        self.subscriber.undeclare()
        self.publisher.undeclare()
