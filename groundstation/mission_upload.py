"""The ground station's side of a mission upload (the MAVLink mission protocol), pure: what to send, from what the
vehicle sent and the wall time (:class:`MissionUpload`); the ground station (:mod:`groundstation.gcs`) sends it.

``MISSION_COUNT`` first and again every UPLOAD_RETRY of wall time while the vehicle asks for no item; each
``MISSION_REQUEST_INT`` (or legacy ``MISSION_REQUEST``, re-requests too) answered with its ``MISSION_ITEM_INT``; done
at ``MISSION_ACK`` ACCEPTED. Any other ``MISSION_ACK`` fails the upload, naming the result, and so does an upload
that has not completed after UPLOAD_TIMEOUT.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from quadsitl import wire

UPLOAD_RETRY = 1.0  # [s] wall: MISSION_COUNT again when the vehicle has not asked for an item
UPLOAD_TIMEOUT = 10.0  # [s] wall: give the upload up


def ack_name(result: int) -> str:
    """A MAV_MISSION_RESULT as its name and number (``MAV_MISSION_UNSUPPORTED (3)``)."""
    entry = wire.mavlink.enums["MAV_MISSION_RESULT"].get(result)
    return f"{entry.name if entry else 'unknown'} ({result})"


class UploadStep(NamedTuple):
    """What one step of the upload sends and says: the items to send (their seq, in the order asked for), whether to
    send MISSION_COUNT, whether the vehicle accepted the mission, and why the upload failed (None: it did not)."""

    items: list[int]
    count: bool
    done: bool
    error: str | None


class MissionUpload:
    """An upload of ``count`` items that started at wall time ``start`` [s, time.monotonic]."""

    def __init__(self, count: int, start: float) -> None:
        self.count = count
        self.start = start
        self.last_sent = 0.0  # [s] wall: MISSION_COUNT last sent, or the vehicle last asked for an item

    def step(self, now: float, requested: Sequence[int], ack: int | None) -> UploadStep:
        """At wall time ``now`` [s], the vehicle having asked for the items ``requested`` (seq; those out of range
        ignored) since the last step, and its MISSION_ACK's result ``ack`` (None: none yet) → what to do."""
        items = [seq for seq in requested if 0 <= seq < self.count]
        if requested:
            self.last_sent = now  # the vehicle is asking: the transfer is under way
        if ack is not None:
            if ack != wire.mavlink.MAV_MISSION_ACCEPTED:
                return UploadStep(items, False, False, f"the vehicle refused the mission: MISSION_ACK {ack_name(ack)}")
            return UploadStep(items, False, True, None)
        if now - self.start > UPLOAD_TIMEOUT:
            return UploadStep(items, False, False, f"the mission upload did not complete within {UPLOAD_TIMEOUT:g} s")
        if now - self.last_sent > UPLOAD_RETRY:
            self.last_sent = now
            return UploadStep(items, True, False, None)
        return UploadStep(items, False, False, None)
