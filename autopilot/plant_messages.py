"""Plant datagrams the compiled decoder does not take whole (other messages with the tick's, signed frames), sorted
out by pymavlink: the per-tick messages of the autopilot's mode re-framed for the compiled path, those of the other
mode refused, and the plant's STATUSTEXT (all its chunks in one datagram: the plant's state diverged and the plant
stopped, :mod:`sitl.process`) joined into one text."""

from __future__ import annotations

from dataclasses import dataclass

from quadsitl import wire

mavlink = wire.mavlink
SENSOR_MESSAGES = frozenset((mavlink.MAVLINK_MSG_ID_HIL_SENSOR, mavlink.MAVLINK_MSG_ID_HIL_GPS,
                             mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION))  # fmt: skip
STATE_MESSAGES = frozenset((mavlink.MAVLINK_MSG_ID_ODOMETRY,))
MODE_MISMATCH = {
    False: "Plant sends sensors (HIL_SENSOR); this autopilot flies on the true state: start both with --state sensors",
    True: "Plant sends the true state (ODOMETRY); this autopilot flies on sensors: start both with --state sensors",
}


@dataclass(frozen=True)
class Sorted:
    """What a datagram held: ``datagrams`` to fly (each ODOMETRY alone; in sensor mode a tick's HIL_SENSOR, HIL_GPS
    and HIL_STATE_QUATERNION together; a BATTERY_STATUS after them with them), how many messages are ``refused``
    (the other mode's; 1 for a datagram that is not MAVLink), whether the ``other_mode``'s were among them, and the
    plant's text: (severity, text) or None."""

    datagrams: list[bytes]
    refused: int
    other_mode: bool
    said: tuple[int, str] | None


def sort_out(mav: wire.mavlink.MAVLink, data: bytes, sensing: bool) -> Sorted:
    """``data`` parsed with ``mav``, for an autopilot flying on sensors (``sensing``) or on the true state."""
    try:
        msgs = mav.parse_buffer(data) or []
    except mavlink.MAVError:
        return Sorted([], 1, False, None)
    said, frames, refused = [], [], 0
    mine, theirs = (SENSOR_MESSAGES, STATE_MESSAGES) if sensing else (STATE_MESSAGES, SENSOR_MESSAGES)
    for msg in msgs:
        mid = msg.get_msgId()
        if mid in mine:
            frames.append(msg.pack(wire.link(msg.get_srcSystem(), msg.get_srcComponent())))
        elif mid == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS and frames:  # the battery's goes with its tick's frames
            frames[-1] += msg.pack(wire.link(msg.get_srcSystem(), msg.get_srcComponent()))
        elif mid in theirs:
            refused += 1
        elif mid == mavlink.MAVLINK_MSG_ID_STATUSTEXT:
            said.append(msg)
    datagrams = [b"".join(frames)] if sensing and frames else frames
    text = None
    if said:
        text = (min(m.severity for m in said), "".join(m.text for m in sorted(said, key=lambda m: m.chunk_seq)))
    return Sorted(datagrams, refused, refused > 0, text)
