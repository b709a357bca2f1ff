"""Failure injection (MAV_CMD_INJECT_FAILURE) as PX4 takes it, pure: which units and types the vehicle takes, and
what each means (docs/failures.md#injected-failures). The plant and the autopilot both read it: the autopilot checks
a command and passes a sensor's failure on to the plant, whose sensors fail physically (:mod:`sitl.sensors`); a
motor's it applies in its own outputs, as PX4's simulated outputs block a failed motor.

What PX4's SITL takes (``SimulatorMavlink::check_failure_injections``, ``FailureInjector``), taken here: the GPS off;
the gyroscope, accelerometer, magnetometer and barometer off or stuck; a motor (instance 1..4, 0: all) off; each
back with OK. The rest (garbage, wrong, slow, delayed, intermittent; other units) is unsupported, as PX4's SITL
answers it, naming what is taken.
"""

from __future__ import annotations

# MAVLink's FAILURE_UNIT and FAILURE_TYPE
GYRO, ACCEL, MAG, BARO, GPS, MOTOR = 0, 1, 2, 3, 4, 101
OK, OFF, STUCK = 0, 1, 2
UNIT_NAMES = {GYRO: "gyro", ACCEL: "accel", MAG: "mag", BARO: "baro", GPS: "GPS", 5: "optical flow", 6: "VIO",
              7: "distance sensor", 8: "airspeed", 100: "battery", MOTOR: "motor", 102: "servo", 103: "avoidance",
              104: "RC signal", 105: "MAVLink signal"}  # fmt: skip
TYPE_NAMES = {OK: "ok", OFF: "off", STUCK: "stuck", 3: "garbage", 4: "wrong", 5: "slow", 6: "delayed",
              7: "intermittent"}  # fmt: skip
SENSORS = (GYRO, ACCEL, MAG, BARO, GPS)
TAKEN: dict[int, tuple[int, ...]] = {GYRO: (OK, OFF, STUCK), ACCEL: (OK, OFF, STUCK), MAG: (OK, OFF, STUCK),
                                     BARO: (OK, OFF, STUCK), GPS: (OK, OFF), MOTOR: (OK, OFF)}  # fmt: skip
MOTORS = 4


def describe(unit: int, kind: int, instance: int = 0) -> str:
    """``unit`` ``kind`` in words, e.g. "GPS off", "motor 2 off"."""
    name = UNIT_NAMES.get(unit, f"unit {unit}")
    which = f" {instance}" if instance else ""
    return f"{name}{which} {TYPE_NAMES.get(kind, f'type {kind}')}"


def refusal(unit: int, kind: int, instance: int, sensing: bool) -> str:
    """Why the failure cannot be injected ("" when it can): a unit or type not taken (naming what is), a motor that is
    not there, a sensor failure on a vehicle flown on its true state (``sensing`` False: no sensors to fail)."""
    taken = TAKEN.get(unit)
    if taken is None or kind not in taken:
        offer = "; ".join(f"{UNIT_NAMES[u]} ({u}): {', '.join(TYPE_NAMES[k] for k in ks)}" for u, ks in TAKEN.items())
        return f"Failure {describe(unit, kind)} not supported; taken: {offer}"
    if unit == MOTOR and not 0 <= instance <= MOTORS:
        return f"Failure {describe(unit, kind, instance)}: no such motor; instances 1..{MOTORS}, 0 for all"
    if unit in SENSORS and not sensing:
        return f"Failure {describe(unit, kind)}: the vehicle flies on its true state; sensors fail with --state sensors"
    return ""


def motors_off(off: int, kind: int, instance: int) -> int:
    """The motors off (bit i: motor i + 1) after motor ``instance`` (0: all) went ``kind`` (OFF, or back: OK)."""
    bits = (1 << MOTORS) - 1 if instance == 0 else 1 << (instance - 1)
    return off | bits if kind == OFF else off & ~bits
