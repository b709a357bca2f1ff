"""The MAVLink parameter protocol of the vehicle (PX4's ``mavlink_parameters``): PARAM_REQUEST_LIST and
PARAM_REQUEST_READ answered with PARAM_VALUE, PARAM_SET checked by the parameter table
(:class:`autopilot.params.ParamStore`) and answered with the value in force."""

from __future__ import annotations

from collections.abc import Callable

from autopilot.outbox import Outbox
from autopilot.params import ParamStore
from autopilot.records import ParamRequest, ParamSet
from quadsitl import wire

mavlink = wire.mavlink


class ParamProtocol:
    """Answers parameter requests from ``params``; ``apply()`` makes accepted values the ones the next tick uses."""

    def __init__(self, params: ParamStore, outbox: Outbox, apply: Callable[[], None]) -> None:
        self.params, self.outbox, self.apply = params, outbox, apply

    def send(self, index: int, name: str, value: float) -> None:
        self.outbox.param_value(index, name, value, len(self.params), self.params.specs[index].integer)

    def on_request(self, r: ParamRequest) -> None:
        """The whole list (``r.name`` None), or one parameter by name or index."""
        if r.name is None:
            for index, name, value in self.params:
                self.send(index, name, value)
            return
        found = self.params.lookup(r.name, r.index)
        if found is not None:
            self.send(*found)

    def on_set(self, r: ParamSet) -> None:
        """A new value: applied, or refused with the reason (counted) and a PARAM_ERROR to its sender (before the
        PARAM_VALUE: MAVSDK takes the first answer); the value in force is sent back either way, and an accepted
        change once more, as PX4 announces it."""
        reason = self.params.set(r.name, r.value)
        found = self.params.lookup(r.name)
        if found is None:
            self.outbox.param_error(-1, r.name, mavlink.MAV_PARAM_ERROR_DOES_NOT_EXIST, r.source)
            self.outbox.say(mavlink.MAV_SEVERITY_WARNING, f"Param set refused: {reason}")
            return
        if reason:
            self.outbox.counters.refused += 1
            self.outbox.param_error(found[0], r.name, mavlink.MAV_PARAM_ERROR_VALUE_OUT_OF_RANGE, r.source)
        else:
            self.apply()
        self.send(*found)  # the value in force: the new one, or the unchanged one when refused
        if not reason:  # and a change announced, as PX4 sends changed parameters again: MAVSDK's subscriptions
            self.send(*found)  # (its failure plugin's to SYS_FAILURE_EN) hear the unsolicited one, not the answer
        if reason:
            self.outbox.say(mavlink.MAV_SEVERITY_WARNING, f"Param set refused: {reason}")
