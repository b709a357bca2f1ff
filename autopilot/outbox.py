"""What the vehicle says to its ground stations, sent from one place: status texts (split into STATUSTEXT chunks),
refusals (counted, and said at most every few seconds per kind), the commander's announcements, command
acknowledgements, parameter values and the mission protocol's answers. Everything goes to every ground link
(:class:`autopilot.ground_link.GroundLinks`)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from autopilot import gcs_messages, mission_protocol
from autopilot.commander import Commander
from autopilot.ground_link import GroundLinks
from autopilot.records import Command, Counters
from quadsitl import wire

mavlink = wire.mavlink
SAY_EVERY = 5.0  # [s] wall: a repeated warning of one kind (a stream of unsupported setpoints) at most this often
REASON_EVERY = 1.0  # [s] wall: the same command refusal at most this often (a flood of bad commands)


class Outbox:
    """The sending side of the ground links. ``on_plan_changed`` is called when a mission upload or clear ended, or
    its progress moved (MISSION_ACK, MISSION_CURRENT): the plan's subscribers are told."""

    def __init__(self, ground: GroundLinks, counters: Counters, on_plan_changed: Callable[[], None]) -> None:
        self.ground, self.counters, self.on_plan_changed = ground, counters, on_plan_changed
        self.chunk_id = 0
        self.said: dict[str, float] = {}  # topic → wall time of the last such warning
        self.on_said: Callable[[int, str], None] | None = None  # (severity, text): each status text also goes here

    def send(self, msg) -> None:
        self.ground.send(msg)

    def say(self, severity: int, text: str) -> None:
        """A STATUSTEXT (in chunks, one id, when longer than one message holds)."""
        if self.on_said is not None:
            self.on_said(severity, text)
        self.chunk_id = self.chunk_id % 65535 + 1
        for msg in gcs_messages.statustext(severity, text, self.chunk_id):
            self.send(msg)

    def say_once(self, topic: str, text: str, every: float = SAY_EVERY) -> None:
        """A warning about a repeated input: at most once per ``every`` seconds of wall time per ``topic``."""
        now = time.monotonic()
        if now - self.said.get(topic, -math.inf) >= every:
            self.said[topic] = now
            self.say(mavlink.MAV_SEVERITY_WARNING, text)

    def refuse(self, topic: str, text: str) -> None:
        """A refused input: counted, and said (at most every SAY_EVERY per kind); the last valid setpoint stays in
        force."""
        self.counters.refused += 1
        self.say_once(topic, text)

    def announce(self, commander: Commander) -> None:
        """What the commander has to say (mode changes, failsafes), said and forgotten."""
        if commander.messages:
            for severity, text in commander.messages:
                self.say(severity, text)
            commander.messages.clear()

    def command_ack(self, c: Command, result: int, reason: str = "", reply=None) -> None:
        """COMMAND_ACK to the command's sender, then the reply (a message the command asked for) and the reason of a
        refusal as a status text (the same reason at most every REASON_EVERY)."""
        self.send(mavlink.MAVLink_command_ack_message(c.command, result, 0, 0, *c.source))
        if reply is not None:
            self.send(reply)
        if reason:
            self.say_once(reason, reason, every=REASON_EVERY)

    def param_value(self, index: int, name: str, value: float, count: int, integer: bool = False) -> None:
        """PARAM_VALUE: parameter ``index`` of ``count``; an ``integer`` one as INT32, bytewise (as PX4)."""
        carried, kind = wire.param_to_wire(value, integer)
        self.send(mavlink.MAVLink_param_value_message(name.encode(), carried, kind, count, index))

    def param_error(self, index: int, name: str, error: int, to: tuple[int, int]) -> None:
        """PARAM_ERROR (MAV_PARAM_ERROR ``error``) to the sender ``to`` of a refused PARAM_SET: MAVSDK ends the set
        with the matching result (ValueOutOfRange, DoesNotExist) instead of resending it until it times out."""
        self.send(mavlink.MAVLink_param_error_message(to[0], to[1], name.encode(), index, error))

    def mission(self, out: mission_protocol.Out) -> None:
        """One of the mission protocol's answers (:class:`autopilot.mission_protocol.Out`)."""
        if out.kind == "STATUSTEXT":
            self.say(out.fields["severity"], out.fields["text"])
        else:
            self.send(getattr(mavlink, f"MAVLink_{out.kind.lower()}_message")(**out.kwargs()))
            if out.kind in ("MISSION_ACK", "MISSION_CURRENT"):
                self.on_plan_changed()
