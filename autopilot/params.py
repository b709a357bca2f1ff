"""The autopilot's MAVLink parameters: a pure table of names, ranges and values, with no I/O.

Every parameter is a REAL32 (MAVLink ``PARAM_VALUE`` carries a float; one type for all avoids the
int-encoding differences between ground stations). The order of :data:`SPECS` is the
``param_index``, so indices are stable and unique and ``param_count`` never changes.

The table holds the autopilot's *own* copy of the vehicle model (DESIGN.md §2): by default it equals the
preset the plant flies, and a user may mismatch it on purpose. A change is checked as a whole before it
is accepted: the value must be in its range, and the resulting controller must build (backstepping
gains must satisfy conditions (41)–(44), ``THR_MIN`` < ``THR_MAX``). :meth:`ParamStore.set` returns why
it refused; a refused set leaves every value as it was.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace

from autopilot.calibration import CalibrationParams
from autopilot.commander import CommanderSettings
from autopilot.factory import PluggedController, make_controller
from autopilot.gains import GainError, rates_from_poles
from autopilot.plugin import Plugged
from quadsitl.config import PD_CHANNELS, ControllerParams, PositionParams, Preset, VehicleParams
from quadsitl.keys import ParamEntry, fields_from_params, param_values, params_of

MAX_NAME = 16  # MAVLink param_id length
CONTROLLER_TYPES = ("backstepping", "pd")
CHANNELS = PD_CHANNELS


@dataclass(frozen=True)
class ParamSpec:
    """One parameter: its range is [lo, hi] (or (lo, hi] with ``lo_open``); ``integer`` values must be whole."""

    name: str
    lo: float
    hi: float
    unit: str
    doc: str
    lo_open: bool = False
    integer: bool = False
    fixed: str = ""  # why the value may not change in this autopilot (its one allowed value is lo)

    def allowed(self) -> str:
        if self.fixed:
            return f"{self.lo:g} ({self.fixed})"
        if self.integer:
            return f"an integer in [{self.lo:g}, {self.hi:g}]"
        left = "(" if self.lo_open else "["
        unit = f" {self.unit}" if self.unit else ""
        return f"a number in {left}{self.lo:g}, {self.hi:g}]{unit}"

    def accepts(self, value: float) -> bool:
        if not math.isfinite(value):
            return False
        if self.fixed:
            return value == self.lo
        if self.integer and value != round(value):
            return False
        above = value > self.lo if self.lo_open else value >= self.lo
        return above and value <= self.hi


# The preset's keys that are parameters, as quadsitl.config declares them (name, range, unit, doc), in index order.
GAINS = params_of(ControllerParams, ("gains", "pd_kp", "pd_kd"))  # BS_K1..BS_K8, PD_*_P, PD_*_D
MODEL = params_of(VehicleParams, doc_prefix="model ")  # VM_*: the autopilot's model of the vehicle
LIMITS = params_of(ControllerParams, ("max_tilt", "thrust_min", "thrust_max"))  # ATT_TILT_MAX, THR_MIN, THR_MAX
POSITION = params_of(PositionParams)  # BS_K9..BS_K12, BS_KI_*, BS_I_LIM, MPC_*


SETPOINTS = params_of(
    CommanderSettings,
    ("setpoint_timeout", "land_speed", "landed_time", "altitude_max", "datalink_timeout", "datalink_action"),
)  # COM_*, MPC_LAND_SPEED, SP_ALT_MAX
MISSIONS = params_of(CommanderSettings, ("takeoff_alt", "rtl_alt", "max_distance"))  # MIS_, RTL_, GF_
HEADING = params_of(CommanderSettings, ("yaw_rate_auto", "yaw_rate_offboard"))  # MPC_YAWRAUTO_MAX, SP_YAWRATE_MAX
SAFETY = params_of(CommanderSettings, ("disarm_preflight", "dist_1wp", "failure_injection", "actuator_failure_action"))
# COM_DISARM_PRFLT, MIS_DIST_1WP, SYS_FAILURE_EN, COM_ACT_FAIL_ACT
GEOFENCE = params_of(CommanderSettings, ("geofence_action", "max_height"))  # GF_ACTION, GF_MAX_VER_DIST
BATTERY = params_of(CommanderSettings, ("bat_low_thr", "bat_crit_thr", "bat_emergen_thr", "low_bat_action"))
# BAT_LOW_THR, BAT_CRIT_THR, BAT_EMERGEN_THR, COM_LOW_BAT_ACT
MANUAL = params_of(CommanderSettings, ("rc_loss_timeout", "rc_loss_action", "rc_loss_except", "rc_in_mode",
                                       "fail_act_t", "man_tilt_max", "man_yaw_rate", "vel_manual", "hold_deadzone",
                                       "xy_expo", "z_expo", "yaw_expo"))  # fmt: skip
# COM_RC_LOSS_T, NAV_RCL_ACT, COM_RCL_EXCEPT, COM_RC_IN_MODE, COM_FAIL_ACT_T, MPC_MAN_TILT_MAX, MPC_MAN_Y_MAX,
# MPC_VEL_MANUAL, MPC_HOLD_DZ, MPC_XY_MAN_EXPO, MPC_Z_MAN_EXPO, MPC_YAW_EXPO
ORBIT = params_of(CommanderSettings, ("orbit_radius_max", "orbit_yaw_mode"))  # MC_ORBIT_RAD_MAX, MC_ORBIT_YAW_MOD
FOLLOW = params_of(
    CommanderSettings,
    (
        "follow_height",
        "follow_distance",
        "follow_angle",
        "follow_altitude_mode",
        "follow_max_speed",
        "follow_responsiveness",
    ),
)  # FLW_TGT_*
CALIBRATION = params_of(CalibrationParams)  # CAL_GYRO0_[XYZ]OFF, SENS_BOARD_X_OFF, SENS_BOARD_Y_OFF
NO_SENSORS = "the vehicle flies on the plant's true state (--state truth): no sensors to calibrate"
SETTINGS = SETPOINTS + MISSIONS + HEADING + SAFETY + GEOFENCE + BATTERY + MANUAL + ORBIT + FOLLOW  # as parameters


def _declared(entries: tuple[ParamEntry, ...]) -> list[ParamSpec]:
    return [ParamSpec(e.name, e.lo, e.hi, e.unit, e.doc, lo_open=e.lo_open, integer=e.integer) for e in entries]


def _specs() -> tuple[ParamSpec, ...]:
    """The table: the controller kind, then the declared keys' parameters (the preset's and the commander's settings),
    in the order clients have always seen them."""
    s: list[ParamSpec] = [ParamSpec("CTL_TYPE", 0, 1, "", "controller: 0 = backstepping, 1 = PD", integer=True)]
    s += _declared(GAINS) + _declared(MODEL) + _declared(LIMITS) + _declared(SETPOINTS) + _declared(POSITION)
    s += _declared(MISSIONS) + _declared(HEADING) + _declared(SAFETY) + _declared(GEOFENCE) + _declared(BATTERY)
    s += _declared(MANUAL) + _declared(ORBIT) + _declared(FOLLOW) + _declared(CALIBRATION)
    for spec in s:
        assert len(spec.name) <= MAX_NAME, spec.name
    return tuple(s)


SPECS: tuple[ParamSpec, ...] = _specs()
INDEX: dict[str, int] = {spec.name: i for i, spec in enumerate(SPECS)}


def values_from(preset: Preset, controller: str, settings: CommanderSettings) -> dict[str, float]:
    """The parameter values that describe ``preset`` flown with ``controller`` and ``settings``."""
    v, c = preset.autopilot_model, preset.controller
    rates = c.gains if c.gains is not None else rates_from_poles(preset.poles(), preset.sim.period)
    out: dict[str, float] = {"CTL_TYPE": float(CONTROLLER_TYPES.index(controller))}
    out.update(param_values(replace(c, gains=tuple(float(k) for k in rates)), GAINS))
    out.update(param_values(v, MODEL))
    out.update(param_values(c, LIMITS))
    out.update(param_values(settings, SETPOINTS))
    out.update(param_values(preset.position, POSITION))
    out.update(param_values(settings, MISSIONS))
    out.update(param_values(settings, HEADING))
    out.update(param_values(settings, SAFETY))
    out.update(param_values(settings, GEOFENCE))
    out.update(param_values(settings, BATTERY))
    out.update(param_values(settings, MANUAL))
    out.update(param_values(settings, ORBIT))
    out.update(param_values(settings, FOLLOW))
    out.update(param_values(CalibrationParams(), CALIBRATION))
    assert set(out) == set(INDEX), set(out) ^ set(INDEX)
    return out


@dataclass(frozen=True)
class Applied:
    """What a set of parameter values means for the autopilot: the model and gains (as a preset),
    the controller kind (a plugged controller's spec, ``path.py:Name``, when CTL_TYPE is 2), the commander's
    settings, and a plugged controller's parameter values by name."""

    preset: Preset
    controller: str
    settings: CommanderSettings
    plugged: dict[str, float] = field(default_factory=dict)
    calibration: CalibrationParams = field(default_factory=CalibrationParams)


PLUGGED_TYPE = len(CONTROLLER_TYPES)  # CTL_TYPE of a plugged controller


def plugged_specs(plugged: Plugged) -> tuple[ParamSpec, ...]:
    """A plugged controller's parameters as MAVLink parameters (quadsitl.controller.Parameter: its name in capitals
    or its own MAVLink name, its range and unit), after the autopilot's own."""
    return tuple(ParamSpec(p.param_id, p.low, p.high, p.unit, p.doc) for p in plugged.parameters)


def apply(base: Preset, base_settings: CommanderSettings, values: dict[str, float],
          plugged: Plugged | None = None) -> Applied:  # fmt: skip
    """Values → the preset, controller kind, commander settings and calibration they describe (and ``plugged``'s
    parameters). The
    preset's actuators (the wire's scale) and simulation settings are not parameters and stay ``base``'s."""
    vehicle = replace(base.autopilot_model, **fields_from_params(values, MODEL))
    controller = replace(base.controller, poles=None, **fields_from_params(values, GAINS),
                         **fields_from_params(values, LIMITS))  # fmt: skip
    position = PositionParams(**fields_from_params(values, POSITION))
    settings = replace(commander_settings(position, base_settings), **fields_from_params(values, SETTINGS))
    kind = int(values["CTL_TYPE"])
    named = {} if plugged is None else {p.name: values[p.param_id] for p in plugged.parameters}
    return Applied(replace(base, vehicle=vehicle, model=(), controller=controller, position=position),
                   plugged.spec if kind == PLUGGED_TYPE and plugged else CONTROLLER_TYPES[kind], settings,
                   named, CalibrationParams(**fields_from_params(values, CALIBRATION)))  # fmt: skip


def commander_settings(position: PositionParams, settings: CommanderSettings) -> CommanderSettings:
    """``settings`` with the limits the auto modes' references share with the position loop (``position``)."""
    p = position
    return replace(
        settings, acc_hor=p.acc_hor, cruise=p.xy_cruise, takeoff_speed=p.takeoff_speed, z_vel_up=p.z_vel_max_up,
        z_vel_dn=p.z_vel_max_dn, xy_vel_max=p.xy_vel_max,
    )  # fmt: skip


class ParamStore:
    """The parameter values of one autopilot, changed only through :meth:`set`. With a ``plugged`` controller
    (:mod:`autopilot.plugin`), CTL_TYPE 2 flies it and its parameters follow the autopilot's own. Without sensors
    (``preset.sensors`` None: truth mode) the calibration's parameters stay 0."""

    def __init__(self, preset: Preset, controller: str, settings: CommanderSettings,
                 plugged: Plugged | None = None) -> None:  # fmt: skip
        settings = commander_settings(preset.position, settings)
        self.base, self.base_settings, self.plugged = preset, settings, plugged
        self.specs = SPECS
        if plugged is not None:
            ctl = ParamSpec("CTL_TYPE", 0, PLUGGED_TYPE, "", f"controller: 0 = backstepping, 1 = PD, 2 = "
                            f"{plugged.cls.__name__}", integer=True)  # fmt: skip
            own = plugged_specs(plugged)
            clash = sorted({s.name for s in own} & set(INDEX))
            if clash:
                raise ValueError(f"controller {plugged.spec}: parameter {clash[0]} is one of the autopilot's own")
            self.specs = (ctl, *SPECS[1:], *own)
        if preset.sensors is None:
            fixed = {e.name for e in CALIBRATION}
            self.specs = tuple(replace(s, lo=0.0, hi=0.0, fixed=NO_SENSORS) if s.name in fixed else s
                               for s in self.specs)  # fmt: skip
        self.index = {spec.name: i for i, spec in enumerate(self.specs)}
        plug = plugged is not None and controller == plugged.spec
        self.values = values_from(preset, "backstepping" if plug else controller, settings)
        if plugged is not None:
            self.values["CTL_TYPE"] = float(PLUGGED_TYPE) if plug else self.values["CTL_TYPE"]
            self.values.update({p.param_id: float(p.default) for p in plugged.parameters})

    def __len__(self) -> int:
        return len(self.specs)

    def __iter__(self) -> Iterator[tuple[int, str, float]]:
        """(index, name, value) in index order."""
        for i, spec in enumerate(self.specs):
            yield i, spec.name, self.values[spec.name]

    def lookup(self, name: str | None = None, index: int = -1) -> tuple[int, str, float] | None:
        """By name, or by index when ``index`` ≥ 0 (MAVLink's PARAM_REQUEST_READ rule). None if unknown."""
        if index >= 0:
            if index >= len(self.specs):
                return None
            name = self.specs[index].name
        if name not in self.index:
            return None
        return self.index[name], name, self.values[name]

    def set(self, name: str, value: float, build: Callable[[Applied], object] | None = None) -> str:
        """Set ``name`` to ``value``. Returns "" when accepted, else the reason it was refused (the
        values are then unchanged). ``build`` (default: make the controller) is called with the
        candidate; a :class:`GainError` or ``ValueError`` it raises refuses the change."""
        if name not in self.index:
            return f"{name}: no such parameter"
        spec = self.specs[self.index[name]]
        if not spec.accepts(value):
            return f"{name} = {value:g}: expected {spec.allowed()}"
        candidate = {**self.values, name: float(value)}
        if candidate["THR_MIN"] >= candidate["THR_MAX"]:
            return f"{name} = {value:g}: THR_MIN must be below THR_MAX"
        applied = apply(self.base, self.base_settings, candidate, self.plugged)
        try:
            (build or self.build)(applied)
        except (GainError, ValueError) as exc:
            return f"{name} = {value:g}: {exc}"
        self.values = candidate
        return ""

    def applied(self) -> Applied:
        return apply(self.base, self.base_settings, self.values, self.plugged)

    def build(self, applied: Applied) -> object:
        """The controller ``applied`` describes (the backstepping's gains are checked against (41)–(44) whichever
        controller flies: its the failsafe's), a plugged one on the model with its parameters, checked and probed
        (:meth:`autopilot.plugin.Plugged.plug`; a refusal is a ValueError)."""
        base = make_controller(applied.preset, "backstepping")
        if self.plugged is not None and applied.controller == self.plugged.spec:
            return PluggedController(self.plugged, base, applied.plugged)
        return make_controller(applied.preset, applied.controller)
