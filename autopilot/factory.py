"""Build a controller from a preset (and optional overrides of the gains)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from autopilot import plugin
from autopilot.backstepping import BacksteppingController
from autopilot.control_params import KINDS, PLUGGED
from autopilot.gains import check_position_gains, poles_from_rates, rates_from_poles
from autopilot.pd import PDController
from quadsitl.config import Preset

CONTROLLERS = tuple(KINDS)  # backstepping, pd


class PluggedController:
    """A controller loaded from a file or module (:mod:`autopilot.plugin`), flown on the autopilot's model
    (``v``); ``c``: the preset's backstepping, which the failsafe flies when the plugged law commands a non-finite
    value. ``values``: its parameters' values (default: the declared defaults)."""

    kind = PLUGGED

    def __init__(self, plugged: plugin.Plugged, base: BacksteppingController,
                 values: Mapping[str, float] | None = None) -> None:  # fmt: skip
        self.plugged, self.base = plugged, base
        self.v, self.c = base.v, base.c
        self.values = plugged.values(values)
        self.plug = plugged.plug(self.v, self.values)

    @property
    def max_tilt(self) -> float:
        """The bound on attitude setpoints' roll and pitch [rad]: the preset's, as for the built-ins."""
        return self.base.max_tilt


def make_controller(
    preset: Preset,
    kind: str | None = None,
    rates: Sequence[float] | None = None,
    poles: Sequence[float] | None = None,
    position_loop: bool = True,
    values: Mapping[str, float] | None = None,
) -> BacksteppingController | PDController | PluggedController:
    """The preset's controller (or ``kind``: a built-in's name, or a controller to load, ``path/to/file.py:Name`` or
    ``package.module:Name``: :class:`autopilot.plugin.ControllerError` when it cannot be). ``rates`` (k_i, 1/s) or
    ``poles`` (λ_i) override the preset's backstepping gains. Raises :class:`autopilot.gains.GainError` for
    inadmissible gains (the paper's (41)–(44), and with ``position_loop`` the position loop's (53), (56) and
    (58)). ``values``: a plugged controller's parameters by name (default: its defaults)."""
    kind = kind or preset.controller.type
    c = preset.controller
    if plugin.is_plugin(kind):
        base = make_controller(preset, "backstepping", rates, poles, position_loop)
        return PluggedController(plugin.load(kind), base, values)
    if kind not in CONTROLLERS:
        raise ValueError(f"controller {kind!r}: expected one of {', '.join(CONTROLLERS)}, path/to/file.py:Name or "
                         "package.module:Name")  # fmt: skip
    if rates is not None and poles is not None:
        raise ValueError("give rates or poles, not both")
    if rates is not None:
        lam = poles_from_rates(rates, preset.sim.period)
    elif poles is not None:
        lam = tuple(poles)
    else:
        lam = preset.poles()
    T = preset.sim.period
    p = preset.position
    if position_loop:  # the horizontal loop is flown: not by an attitude experiment (the paper's)
        check_position_gains(p.gains, p.integral, rates_from_poles(lam[2:6], T), T)
    if kind == "pd":  # the backstepping's poles ride along: the autopilot switches controllers (CTL_TYPE)
        return PDController(preset.autopilot_model, c.pd_kp, c.pd_kd, c.max_tilt, c.thrust_min, c.thrust_max, T, lam, p)
    return BacksteppingController(
        preset.autopilot_model, T, lam, c.max_tilt, c.thrust_min, c.thrust_max, c.pd_kp, c.pd_kd, position=p
    )
