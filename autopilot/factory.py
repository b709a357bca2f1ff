"""Build a controller from a preset (and optional overrides of the gains)."""

from __future__ import annotations

from collections.abc import Sequence

from autopilot.backstepping import BacksteppingController
from autopilot.control_params import KINDS
from autopilot.gains import check_position_gains, poles_from_rates, rates_from_poles
from autopilot.pd import PDController
from quadsitl.config import Preset

CONTROLLERS = tuple(KINDS)  # backstepping, pd


def make_controller(
    preset: Preset,
    kind: str | None = None,
    rates: Sequence[float] | None = None,
    poles: Sequence[float] | None = None,
    position_loop: bool = True,
) -> BacksteppingController | PDController:
    """The preset's controller (or ``kind``). ``rates`` (k_i, 1/s) or ``poles`` (λ_i) override the
    preset's backstepping gains. Raises :class:`autopilot.gains.GainError` for inadmissible gains (the paper's
    (41)–(44), and with ``position_loop`` the position loop's (53), (56) and (58))."""
    kind = kind or preset.controller.type
    c = preset.controller
    if kind not in CONTROLLERS:
        raise ValueError(f"controller {kind!r}: expected one of {', '.join(CONTROLLERS)}")
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
