"""Modes, arming, setpoints and failsafes: a pure state machine, fed with events and simulated time.

No I/O. The process shell calls ``arm``/``disarm``/``set_mode``/``takeoff``/``reposition``/setpoint handlers
when MAVLink says so, and ``update`` once per control tick; ``update`` leaves the reference to fly in the
state array (a trajectory setpoint as PX4's: position, velocity and acceleration per axis, NaN where not
controlled, or an attitude) and reports events to announce in STATUSTEXT.

Rules (PX4's, DESIGN.md §8–§9):
- Boot: disarmed, HOLD. Arming is allowed in HOLD, TAKEOFF and OFFBOARD; arming into OFFBOARD needs a fresh
  setpoint stream. Switching to OFFBOARD needs a fresh setpoint stream. Home is where the vehicle arms.
- Setpoint stream: SET_ATTITUDE_TARGET and SET_POSITION_TARGET_* feed it; it is fresh while the newest
  arrived within ``setpoint_timeout`` seconds of *simulated* time, or of wall time (the shell tells,
  :meth:`Commander.wall_clock`): a ground station lives on the wall clock and cannot keep pace with a lockstep
  run sped up N×, where PX4's 1 s is 1/N s of its time. The stream is lost when it is stale on both clocks.
- OFFBOARD: each axis group flies its last setpoint: horizontal (x, y: position, velocity or acceleration;
  none given: the last attitude setpoint's roll and pitch, level before one), vertical (altitude or climb
  rate, or an attitude setpoint's collective thrust, flown as it is; the altitude on entering offboard until one
  arrives), heading (yaw, yaw rate, or the heading on
  entry). A setpoint that ignores every field of a group leaves that group as it was.
- Failsafe: in OFFBOARD, a stream older than the timeout switches to LAND and says so.
- TAKEOFF: climb at MPC_TKO_SPEED to the takeoff altitude, then HOLD.
- HOLD: the reference comes to a stop with bounded acceleration (MPC_ACC_HOR) and holds position, altitude
  and heading there, in flight and on the ground; ``reposition`` (DO_REPOSITION, MAVSDK's goto) moves the
  held point at MPC_XY_CRUISE (or the speed given).
- RTL: climb to RTL_RETURN_ALT (when lower), fly home at MPC_XY_CRUISE, then land there.
- MISSION: flies as HOLD does, toward the targets the mission executor gives (:meth:`Commander.goto`,
  autopilot.missions).
- LAND (and RTL's last phase): brake to a stop (velocity reference 0, as fast as the tilt limit allows), then
  hold that point while the altitude reference descends (at MPC_Z_VEL_MAX_DN above 10 m, at ``land_speed``
  below 5 m) to below the ground; touchdown
  (altitude < 5 cm, |climb| < 0.1 m/s for ``landed_time``) disarms.
- Automatic disarming (PX4's, :func:`auto_disarm`): armed and not taken off within COM_DISARM_PRFLT, or resting on
  the ground for COM_DISARM_LAND after a flight, in any mode.
- Manual modes (PX4's, :mod:`autopilot.manual`, docs/manual.md): MANUAL_CONTROL's sticks fly STABILIZED (attitude,
  yaw rate, thrust), ALTCTL (attitude, yaw rate, climb rate; centred throttle holds the altitude) and POSCTL
  (velocity; centred sticks hold the position). Arming in them or switching to them needs fresh sticks.
- The sticks' loss (PX4's, :func:`_sticks`): none for COM_RC_LOSS_T (simulated and wall time) in flight, having had
  them since arming, is NAV_RCL_ACT's failsafe (not in the modes COM_RCL_EXCEPT names), a return or landing after
  COM_FAIL_ACT_T in hold; a hold it made returns to the mode it left when they come back.
- Battery (PX4's, :func:`_battery`): below BAT_LOW_THR, BAT_CRIT_THR, BAT_EMERGEN_THR of its charge it is low,
  critical, at emergency; while armed the level only rises, and each new level worse than at arming takes
  COM_LOW_BAT_ACT's action (critical: return or land; emergency: land, or return for 1). Critical or worse denies
  arming.

The per-tick part (:func:`update`) is compiled (:mod:`quadsitl.jit`) and works on the commander's state,
one float64 array with a name per index, so the autopilot's whole tick runs as one compiled call
(:mod:`autopilot.tick`). The events are ordinary Python methods of :class:`Commander` on the same array,
and the messages to announce are Python strings. The auto modes' references come from
:func:`advance_reference`: a point moving toward a target with bounded speed and acceleration.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

# The state's layout (generated names), modes, failsafes, events and settings, re-exported for the commander's users
from autopilot import geofence, manual
from autopilot.commander_state import *  # noqa: F403
from quadsitl.compiled_frames import wrap_pi
from quadsitl.jit import jit
from quadsitl.state import Reference, VehicleState
from quadsitl.wire import Mode

if TYPE_CHECKING:
    from autopilot.records import AttitudeSetpoint, FollowTarget, ManualControl, TrajectorySetpoint


@jit
def stream_fresh(cm: np.ndarray) -> bool:
    return cm[NOW] - cm[LAST_SP_TIME] <= cm[SETPOINT_TIMEOUT] or cm[SP_WALL_FRESH] == 1.0


@jit
def sticks_fresh(cm: np.ndarray) -> bool:
    """Whether the sticks are live: the newest within COM_RC_LOSS_T of simulated time or of wall time, and taken."""
    if cm[RC_IN_MODE] == 0.0 or cm[RC_IN_MODE] == RC_IN_MODE_DISABLED:
        return False
    return cm[NOW] - cm[STICK_TIME] <= cm[RC_LOSS_T] or cm[STICK_WALL_FRESH] == 1.0


@jit
def stop_distance(v: float, a: float) -> float:
    """Signed distance [m] to stop from speed ``v`` at deceleration ``a``."""
    return v * abs(v) / (2.0 * a)


@jit
def start_here(cm: np.ndarray) -> None:
    """The auto modes' reference started at the vehicle (position and velocity, no acceleration), its target where
    the vehicle can stop (at MPC_ACC_HOR, not below the ground)."""
    a = cm[ACC_HOR]
    # Resting on the ground, the reference starts and stays on it: an estimated altitude and climb rate (sensor
    # mode) that wander by centimetres must not make a target above the vehicle, which would lift it off.
    landed = cm[ALTITUDE] < TOUCHDOWN_ALT and abs(cm[CLIMB_RATE]) < TOUCHDOWN_CLIMB
    cm[GEN_X], cm[GEN_Y], cm[GEN_ALT] = cm[X], cm[Y], 0.0 if landed else max(cm[ALTITUDE], 0.0)
    cm[GEN_VX], cm[GEN_VY], cm[GEN_CLIMB] = cm[VX], cm[VY], 0.0 if landed else cm[CLIMB_RATE]
    cm[GEN_AX], cm[GEN_AY], cm[GEN_CLIMB_ACC] = 0.0, 0.0, 0.0
    cm[TARGET_X] = cm[X] + stop_distance(cm[VX], a)
    cm[TARGET_Y] = cm[Y] + stop_distance(cm[VY], a)
    cm[TARGET_ALT] = 0.0 if landed else max(cm[ALTITUDE] + stop_distance(cm[CLIMB_RATE], a), 0.0)


@jit(inline=True)
def enter(cm: np.ndarray, mode: int) -> None:
    """Switch to ``mode``. Auto modes start their reference at the vehicle (position and velocity), aimed at
    where it can stop (not below the ground), heading as now (:func:`_entered`)."""
    cm[MODE] = mode
    _entered(cm)


@jit
def _entered(cm: np.ndarray) -> None:
    """:func:`enter`'s work for the mode in cm[MODE], in one compiled function: called with each mode as a constant,
    numba would compile it once per mode."""
    mode = int(cm[MODE])
    cm[LANDED_SINCE] = math.nan
    cm[OFFBOARD_TICK] = -1.0  # an offboard flight starts at the next tick (set in update)
    cm[REF_THROTTLE] = math.nan  # STABILIZED's alone
    if mode in (POSCTL, ALTCTL, STABILIZED):  # the sticks move the reference from the vehicle's velocity and heading
        cm[GEN_VX], cm[GEN_VY] = cm[VX], cm[VY]
        cm[HOLD_YAW] = cm[YAW_REF] = cm[YAW]
        cm[ALT_LOCK], cm[POS_LOCK_X], cm[POS_LOCK_Y] = math.nan, math.nan, math.nan
        return
    if mode == OFFBOARD:
        vertical = (cm[SP_ALT], cm[SP_CLIMB], cm[SP_CLIMB_ACC], cm[SP_THRUST])
        if math.isnan(vertical[0]) and math.isnan(vertical[1]) and math.isnan(vertical[2]) and math.isnan(vertical[3]):
            cm[SP_ALT] = cm[ALTITUDE]
        cm[HOLD_YAW] = cm[YAW_REF] = cm[YAW]
        cm[ALT_LOCK] = math.nan
        return
    start_here(cm)
    cm[HOLD_YAW] = cm[YAW_REF] = cm[YAW]
    cm[LEG_SPEED], cm[LEG_CLIMB], cm[LEG_DESCENT] = cm[CRUISE], math.nan, math.nan
    cm[PHASE] = 0.0
    cm[LAND_ALT] = cm[TARGET_ALT]
    if mode == TAKEOFF:
        cm[TARGET_ALT] = cm[TAKEOFF_ALT]
    elif mode == ORBIT:  # to the circle first, then around it from rest
        cm[ORBIT_APPROACH], cm[ORBIT_SPEED], cm[ORBIT_ANGLE], cm[ALT_LOCK] = 1.0, 0.0, 0.0, math.nan
    elif mode == FOLLOW:  # around the target from where the vehicle is; held until a target reports
        bearing = math.atan2(cm[Y] - cm[TGT_Y], cm[X] - cm[TGT_X])
        cm[FOLLOW_ANGLE] = bearing if math.isfinite(bearing) else cm[TGT_COURSE] + cm[FLW_FA]
        cm[FOLLOW_RATE], cm[TGT_LOST] = 0.0, 0.0
    elif mode == RTL:
        cm[TARGET_ALT] = max(cm[TARGET_ALT], cm[HOME_ALT] + cm[RTL_ALT])
        geofence.return_destination(cm)


@jit
def arm(cm: np.ndarray) -> None:
    """Arm in the current mode (the checks are :meth:`Commander.arm`'s): home is here, the mode entered afresh."""
    cm[ARMED] = 1.0
    cm[FAILSAFE] = FAILSAFE_NONE
    cm[HOME_X], cm[HOME_Y], cm[HOME_ALT], cm[HOME_YAW] = cm[X], cm[Y], max(cm[ALTITUDE], 0.0), cm[YAW]
    cm[ARMED_AT], cm[TOOK_OFF], cm[RESTING_SINCE], cm[ARM_WALL_RECENT] = cm[NOW], 0.0, math.nan, 0.0
    cm[NO_POSITION] = 0.0  # armed only with a position (the pre-arm check)
    cm[BAT_WARNING_ARMED] = cm[BAT_WARNING]
    cm[STICK_LOST_ARMED] = 0.0 if sticks_fresh(cm) else 1.0  # lost at arming: their loss is no failsafe until they come
    enter(cm, int(cm[MODE]))


@jit
def auto_disarm(cm: np.ndarray, now: float) -> int:
    """PX4's automatic disarming (``Commander::handleAutoDisarm``), in every mode: not taken off (above AIRBORNE_ALT)
    within COM_DISARM_PRFLT of arming (simulated time, and wall time when the shell keeps ARM_WALL_RECENT: a ground
    station on the wall clock gets its seconds in a lockstep run sped up N×) → EVENT_PREFLIGHT_DISARM; resting on
    the ground for COM_DISARM_LAND after taking off → EVENT_LANDED. A landing of LAND or RTL disarms by its own
    count (:func:`_land`), and one amid a mission does not (PX4's ``landed_amid_mission``). Disarms and returns the
    event, or EVENT_NONE."""
    if cm[ALTITUDE] > AIRBORNE_ALT:
        cm[TOOK_OFF] = 1.0
    if cm[TOOK_OFF] == 0.0:
        limit = cm[DISARM_PREFLIGHT]
        if limit > 0.0 and now - cm[ARMED_AT] >= limit and cm[ARM_WALL_RECENT] == 0.0:
            cm[ARMED], cm[OFFBOARD_TICK] = 0.0, -1.0
            return EVENT_PREFLIGHT_DISARM
        return EVENT_NONE
    mode = cm[MODE]
    resting = cm[ALTITUDE] < TOUCHDOWN_ALT and abs(cm[CLIMB_RATE]) < TOUCHDOWN_CLIMB
    if mode in (LAND, RTL, MISSION) or not resting:
        cm[RESTING_SINCE] = math.nan
        return EVENT_NONE
    if math.isnan(cm[RESTING_SINCE]):
        cm[RESTING_SINCE] = now
    elif now - cm[RESTING_SINCE] >= cm[LANDED_TIME]:
        cm[ARMED], cm[OFFBOARD_TICK] = 0.0, -1.0
        return EVENT_LANDED
    return EVENT_NONE


@jit
def advance_reference(cm: np.ndarray, dt: float, speed: float, up: float, down: float) -> bool:
    """Move the auto modes' reference toward its target over ``dt`` [s]: horizontally along the straight line at
    up to ``speed``, vertically at up to ``up``/``down`` [m/s], each with acceleration up to ACC_HOR, slowing
    so as to stop on the target (speed ≤ √(2·a·distance)). Returns True once the reference rests on the target."""
    a = cm[ACC_HOR]
    dv_max = a * dt
    # horizontal
    dx, dy = cm[TARGET_X] - cm[GEN_X], cm[TARGET_Y] - cm[GEN_Y]
    d = math.sqrt(dx * dx + dy * dy)
    want_x = want_y = 0.0
    if d > 0.0:
        s = min(speed, math.sqrt(2.0 * a * d)) / d
        want_x, want_y = dx * s, dy * s
    ddx, ddy = want_x - cm[GEN_VX], want_y - cm[GEN_VY]
    n = math.sqrt(ddx * ddx + ddy * ddy)
    if n > dv_max:
        ddx, ddy = ddx * dv_max / n, ddy * dv_max / n
    vx, vy = cm[GEN_VX] + ddx, cm[GEN_VY] + ddy
    h_done = False
    if d <= math.sqrt(vx * vx + vy * vy) * dt + 1e-9 and abs(want_x) + abs(want_y) <= 2.0 * dv_max:
        cm[GEN_X], cm[GEN_Y], vx, vy, ddx, ddy = cm[TARGET_X], cm[TARGET_Y], 0.0, 0.0, 0.0, 0.0
        h_done = True
    else:
        cm[GEN_X] += vx * dt
        cm[GEN_Y] += vy * dt
    cm[GEN_VX], cm[GEN_VY] = vx, vy
    cm[GEN_AX], cm[GEN_AY] = (ddx / dt, ddy / dt) if dt > 0.0 else (0.0, 0.0)
    # vertical
    dz = cm[TARGET_ALT] - cm[GEN_ALT]
    want = 0.0
    if dz > 0.0:
        want = min(up, math.sqrt(2.0 * a * dz))
    elif dz < 0.0:
        want = -min(down, math.sqrt(-2.0 * a * dz))
    dc = min(max(want - cm[GEN_CLIMB], -dv_max), dv_max)
    climb = cm[GEN_CLIMB] + dc
    v_done = False
    if abs(dz) <= abs(climb) * dt + 1e-9 and abs(want) <= 2.0 * dv_max:
        cm[GEN_ALT], climb, dc = cm[TARGET_ALT], 0.0, 0.0
        v_done = True
    else:
        cm[GEN_ALT] += climb * dt
    cm[GEN_CLIMB] = climb
    cm[GEN_CLIMB_ACC] = dc / dt if dt > 0.0 else 0.0
    return h_done and v_done


@jit
def turn_heading(cm: np.ndarray, wanted: float, rate: float, dt: float) -> None:
    """The heading flown (cm[YAW_REF]) turned toward ``wanted`` [rad] the short way, at up to ``rate`` [rad/s] over
    ``dt`` [s], into the reference (REF_YAW; REF_YAW_RATE 0): a new heading is turned to as PX4 turns to it
    (MPC_YAWRAUTO_MAX; SP_YAWRATE_MAX as its MC_YAWRATE_MAX), not stepped, so a large turn neither tilts the
    vehicle past its limits nor costs it height."""
    error = wrap_pi(wanted - cm[YAW_REF])
    step = rate * dt
    if abs(error) <= step:
        cm[YAW_REF], cm[REF_YAW_RATE] = wanted, 0.0
    else:
        cm[YAW_REF] = wrap_pi(cm[YAW_REF] + math.copysign(step, error))
        cm[REF_YAW_RATE] = 0.0  # no rate feed-forward: it would ask for the whole rate at once
    cm[REF_YAW] = cm[YAW_REF]


@jit
def _fly_generated(cm: np.ndarray, dt: float) -> None:
    """The auto modes' reference: position with velocity and acceleration feed-forward, the heading turned toward
    the one held at up to MPC_YAWRAUTO_MAX."""
    cm[REF_X], cm[REF_Y], cm[REF_VX], cm[REF_VY] = cm[GEN_X], cm[GEN_Y], cm[GEN_VX], cm[GEN_VY]
    cm[REF_AX], cm[REF_AY] = cm[GEN_AX], cm[GEN_AY]
    cm[REF_ALT], cm[REF_CLIMB], cm[REF_CLIMB_ACC] = cm[GEN_ALT], cm[GEN_CLIMB], cm[GEN_CLIMB_ACC]
    cm[REF_ROLL], cm[REF_PITCH] = 0.0, 0.0
    turn_heading(cm, cm[HOLD_YAW], cm[YAW_RATE_AUTO], dt)
    cm[REF_LIMITED], cm[REF_THRUST] = 1.0, math.nan


@jit
def _land(cm: np.ndarray, dt: float, now: float) -> int:
    """A landing's tick: brake to a stop (the velocity reference 0, the altitude held), then hold that point while
    the altitude reference descends at LAND_SPEED; disarm after resting on the ground. With the horizontal position
    lost (cm[NO_POSITION]), PX4's Descend: no braking, no point held, level while the altitude reference descends."""
    if cm[MODE] == LAND and cm[PHASE] == LAND_BRAKING:
        if math.sqrt(cm[VX] ** 2 + cm[VY] ** 2) >= LAND_BRAKED and cm[NO_POSITION] == 0.0:
            advance_reference(cm, dt, 0.0, cm[Z_VEL_UP], cm[Z_VEL_DN])  # only the altitude moves
            _fly_generated(cm, dt)
            cm[REF_X], cm[REF_Y], cm[REF_VX], cm[REF_VY], cm[REF_AX], cm[REF_AY] = (
                math.nan,
                math.nan,
                0.0,
                0.0,
                0.0,
                0.0,
            )
            return EVENT_NONE
        cm[PHASE] = LAND_DESCENDING  # stopped (nearly): hold here, descend
        cm[GEN_X], cm[GEN_Y], cm[GEN_VX], cm[GEN_VY] = cm[X], cm[Y], cm[VX], cm[VY]
        cm[TARGET_X] = cm[X] + stop_distance(cm[VX], cm[ACC_HOR])
        cm[TARGET_Y] = cm[Y] + stop_distance(cm[VY], cm[ACC_HOR])
    advance_reference(cm, dt, cm[LEG_SPEED], cm[Z_VEL_UP], cm[Z_VEL_DN])
    # The altitude reference descends, from where it was, to below the ground: at land_speed below LAND_ALT2, at
    # MPC_Z_VEL_MAX_DN above LAND_ALT1, in between linearly (PX4's MPC_LAND_ALT1/2).
    alt = min(cm[LAND_ALT], cm[GEN_ALT])
    share = min(max((alt - LAND_ALT2) / (LAND_ALT1 - LAND_ALT2), 0.0), 1.0)
    speed = cm[LAND_SPEED] + share * max(cm[Z_VEL_DN] - cm[LAND_SPEED], 0.0)
    cm[LAND_ALT] = max(cm[LAND_TARGET], alt - speed * dt)
    cm[GEN_ALT] = cm[TARGET_ALT] = cm[LAND_ALT]
    cm[GEN_CLIMB] = -speed if cm[LAND_ALT] > cm[LAND_TARGET] else 0.0
    cm[GEN_CLIMB_ACC] = 0.0
    _fly_generated(cm, dt)
    if cm[NO_POSITION] != 0.0:  # PX4's Descend: no position to hold, the vehicle level (roll and pitch 0) goes down
        for i in (REF_X, REF_Y, REF_VX, REF_VY, REF_AX, REF_AY):
            cm[i] = math.nan
    if cm[ALTITUDE] < TOUCHDOWN_ALT and abs(cm[CLIMB_RATE]) < TOUCHDOWN_CLIMB:
        if math.isnan(cm[LANDED_SINCE]):
            cm[LANDED_SINCE] = now
        elif now - cm[LANDED_SINCE] >= cm[LANDED_TIME]:
            cm[ARMED] = 0.0
            cm[OFFBOARD_TICK] = -1.0
            return EVENT_LANDED
    else:
        cm[LANDED_SINCE] = math.nan
    return EVENT_NONE


@jit
def _fly_offboard(cm: np.ndarray, dt: float) -> None:
    """The offboard setpoints as this tick's reference (module docstring)."""
    horizontal = not (
        math.isnan(cm[SP_X]) and math.isnan(cm[SP_VX]) and math.isnan(cm[SP_AX])
        and math.isnan(cm[SP_Y]) and math.isnan(cm[SP_VY]) and math.isnan(cm[SP_AY])
    )  # fmt: skip
    for i in range(6):
        cm[REF_X + i] = cm[SP_X + i]
    cm[REF_ALT], cm[REF_CLIMB], cm[REF_CLIMB_ACC] = cm[SP_ALT], cm[SP_CLIMB], cm[SP_CLIMB_ACC]
    cm[REF_THRUST] = cm[SP_THRUST]
    if math.isnan(cm[SP_ALT]) and cm[SP_CLIMB] == 0.0 and (math.isnan(cm[SP_CLIMB_ACC]) or cm[SP_CLIMB_ACC] == 0.0):
        # A climb rate of zero holds the altitude where the vehicle stops (as PX4's altitude modes lock it), so
        # what the velocity loop lets slip in turns and reversals is flown back, not kept.
        if math.isnan(cm[ALT_LOCK]):
            cm[ALT_LOCK] = max(cm[ALTITUDE] + stop_distance(cm[CLIMB_RATE], cm[ACC_HOR]), 0.0)
        cm[REF_ALT] = cm[ALT_LOCK]
    else:
        cm[ALT_LOCK] = math.nan
    if math.isnan(cm[ROLL_SP]) or horizontal:
        cm[REF_ROLL], cm[REF_PITCH] = 0.0, 0.0
    else:
        cm[REF_ROLL], cm[REF_PITCH] = cm[ROLL_SP], cm[PITCH_SP]
    attitude = not horizontal and not math.isnan(cm[ROLL_SP])  # an attitude setpoint flown: its heading as it is
    if math.isnan(cm[YAW_SP]) and math.isnan(cm[SP_YAW_RATE]):
        cm[REF_YAW], cm[REF_YAW_RATE] = cm[HOLD_YAW], math.nan
        cm[YAW_REF] = cm[HOLD_YAW]
    elif math.isnan(cm[YAW_SP]) or attitude:
        cm[REF_YAW], cm[REF_YAW_RATE] = cm[YAW_SP], cm[SP_YAW_RATE]
        cm[YAW_REF] = cm[YAW] if math.isnan(cm[YAW_SP]) else cm[YAW_SP]
    else:
        turn_heading(cm, cm[YAW_SP], cm[YAW_RATE_OFFBOARD], dt)
        if not math.isnan(cm[SP_YAW_RATE]):
            cm[REF_YAW_RATE] += cm[SP_YAW_RATE]
    cm[REF_LIMITED] = 1.0 if horizontal else 0.0


@jit
def _geofence(cm: np.ndarray) -> int:
    """A new breach of the geofence (autopilot.geofence): GF_ACTION's action, once (not again until the vehicle is back
    inside), not while landing, nor while returning unless it terminates → EVENT_GEOFENCE (taken, or a warning),
    EVENT_GEOFENCE_GOING_ON (a landing or return goes on), or EVENT_NONE."""
    kind = geofence.breach(cm)
    if kind == 0 or cm[GF_BREACH] != 0.0:
        cm[GF_BREACH] = kind
        return EVENT_NONE
    cm[GF_BREACH] = kind
    action = int(cm[GF_ACTION])
    mode = cm[MODE]
    if action == 1:
        return EVENT_GEOFENCE
    if mode == LAND or (mode == RTL and action != 4):  # already coming down or back
        return EVENT_GEOFENCE_GOING_ON
    cm[FAILSAFE] = FAILSAFE_GEOFENCE
    if action == 4:  # terminate: the motors off, the vehicle falls
        cm[ARMED] = 0.0
        cm[OFFBOARD_TICK] = -1.0
    elif action == 2 and mode != HOLD:
        enter(cm, HOLD)
    elif action == 3:
        enter(cm, RTL)
    elif action == 5:
        enter(cm, LAND)
    return EVENT_GEOFENCE


@jit
def battery_seen(cm: np.ndarray, values: tuple[float, float, float, float, float]) -> None:
    """The battery's BATTERY_STATUS (:func:`quadsitl.hil.battery_values`: voltage [V], current [A], charge drawn
    [mAh], energy drawn [J], share left), as the commander keeps it."""
    for i in range(5):
        cm[BAT_V + i] = values[i]


@jit
def battery_level(cm: np.ndarray) -> int:
    """The battery's warning level for its share left (BATTERY_WARNINGS' index; 0 without a battery): below
    BAT_EMERGEN_THR emergency, below BAT_CRIT_THR critical, below BAT_LOW_THR low, as PX4's battery."""
    r = cm[BAT_REMAINING]
    if r < cm[BAT_EMERGEN]:
        return 3
    if r < cm[BAT_CRIT]:
        return 2
    return 1 if r < cm[BAT_LOW] else 0


@jit
def battery_action(cm: np.ndarray, level: int) -> int:
    """The mode COM_LOW_BAT_ACT flies the battery's new warning ``level`` in (PX4's ``fromBatteryWarningActParam``),
    or HOLD for a warning alone: critical, return (1, 3) or land (2); emergency, return (1) or land (2, 3); a warning
    for the low level, for a level no worse than at arming, and for a vehicle that has not taken off."""
    action = int(cm[BAT_ACTION]) if level > cm[BAT_WARNING_ARMED] and cm[TOOK_OFF] != 0.0 else 0
    if level < 2 or action == 0:
        return HOLD
    return RTL if action == 1 or (action == 3 and level == 2) else LAND


@jit
def _battery(cm: np.ndarray) -> int:
    """The battery's level (:func:`battery_level`): disarmed, as it is; armed, it only rises (PX4's commander), and a
    new level takes COM_LOW_BAT_ACT's action (:func:`battery_action`). A landing goes on; a return goes on unless the
    action is to land. → EVENT_BATTERY when the level rose while armed, else EVENT_NONE."""
    level = battery_level(cm)
    if cm[ARMED] == 0.0:
        cm[BAT_WARNING] = level
        return EVENT_NONE
    if level <= cm[BAT_WARNING]:
        return EVENT_NONE
    cm[BAT_WARNING] = level
    target = battery_action(cm, level)
    if target == HOLD or cm[MODE] in (LAND, target):  # a warning, or already coming down or back
        return EVENT_BATTERY
    cm[FAILSAFE] = FAILSAFE_BATTERY
    enter(cm, target)
    return EVENT_BATTERY


@jit
def rc_loss_action(cm: np.ndarray) -> int:
    """What the sticks' loss does in the current mode (RC_LOSS_ACTIONS' index): NAV_RCL_ACT's action, none in a mode
    COM_RCL_EXCEPT names; in a manual mode, which cannot fly without them, a return where NAV_RCL_ACT takes none (PX4's
    mode fallback)."""
    mode, bits = cm[MODE], int(cm[RCL_EXCEPT])
    if ((mode == MISSION and bits & RCL_EXCEPT_MISSION) or (mode in (HOLD, TAKEOFF) and bits & RCL_EXCEPT_HOLD)
            or (mode == OFFBOARD and bits & RCL_EXCEPT_OFFBOARD)):  # fmt: skip
        return 0
    action = int(cm[RCL_ACT])
    if action in (0, 4) and mode in (POSCTL, ALTCTL, STABILIZED):
        return 2
    return 0 if action == 4 else action


@jit
def _sticks(cm: np.ndarray) -> int:
    """The sticks' loss and return (PX4's RC-loss failsafe). Newly lost in flight, having come since arming:
    :func:`rc_loss_action`'s action, kept in cm[STICK_ACTION] → EVENT_STICKS_LOST. A landing goes on, and a return
    unless the action is to land; terminate and disarm act at once; return and land come after COM_FAIL_ACT_T of
    simulated time in hold (PX4's failsafe delay, cm[STICK_DEADLINE]) → EVENT_STICKS_ACTION then. Back after a loss
    → EVENT_STICKS_REGAINED, and a hold the loss made (its delay, or its action) returns to the mode it left, as PX4
    clears a failsafe whose cause cleared. Else EVENT_NONE."""
    fresh = sticks_fresh(cm)
    was = cm[STICK_LOST]
    if fresh:
        cm[STICK_LOST], cm[STICK_LOST_ARMED] = STICKS_LIVE, 0.0
        if was != STICKS_LOST:  # live, or the first sticks since boot
            return EVENT_NONE
        cm[STICK_DEADLINE] = math.nan
        before = int(cm[STICK_MODE_BEFORE])
        if cm[FAILSAFE] == FAILSAFE_MANUAL_CONTROL and cm[MODE] != RTL and cm[MODE] != LAND:  # not taken, or a hold
            cm[FAILSAFE] = FAILSAFE_NONE
            if cm[ARMED] != 0.0 and cm[MODE] == HOLD and before != HOLD:
                enter(cm, before)
        return EVENT_STICKS_REGAINED
    if was == STICKS_LOST and not math.isnan(cm[STICK_DEADLINE]) and cm[NOW] >= cm[STICK_DEADLINE]:
        cm[STICK_DEADLINE] = math.nan
        if cm[ARMED] == 0.0 or cm[MODE] != HOLD or cm[FAILSAFE] != FAILSAFE_MANUAL_CONTROL:
            return EVENT_NONE  # the pilot chose another mode meanwhile (PX4: a mode change clears it), or landed
        enter(cm, RTL if cm[STICK_ACTION] == 2 else LAND)
        return EVENT_STICKS_ACTION
    if was != STICKS_LIVE:
        return EVENT_NONE
    cm[STICK_LOST] = STICKS_LOST
    if cm[ARMED] == 0.0 or cm[STICK_LOST_ARMED] != 0.0:
        return EVENT_NONE
    action = rc_loss_action(cm)
    mode = cm[MODE]
    cm[STICK_ACTION], cm[STICK_MODE_BEFORE] = action, mode
    if action == 0:
        return EVENT_STICKS_LOST
    if mode == LAND or (mode == RTL and action != 3):  # already coming down or back
        cm[STICK_ACTION] = RC_LOSS_GOES_ON
        return EVENT_STICKS_LOST
    cm[FAILSAFE] = FAILSAFE_MANUAL_CONTROL
    if action >= 5:  # terminate, or disarm: the motors off, the vehicle falls
        cm[ARMED], cm[OFFBOARD_TICK] = 0.0, -1.0
        return EVENT_STICKS_LOST
    if mode != HOLD:
        enter(cm, HOLD)
    if action != 1:  # return or land: after the delay, or at once without one
        if cm[FAIL_ACT_T] > 0.0:
            cm[STICK_DEADLINE] = cm[NOW] + cm[FAIL_ACT_T]
        else:
            enter(cm, RTL if action == 2 else LAND)
    return EVENT_STICKS_LOST


@jit
def _manual_heading(cm: np.ndarray, rate: float) -> None:
    """The manual modes' heading: the yaw stick's ``rate`` [rad/s] flown as a yaw rate; centred, the heading where it
    centred held (PX4's ``StickYaw``)."""
    if rate != 0.0:
        cm[HOLD_YAW] = cm[YAW]
        cm[REF_YAW], cm[REF_YAW_RATE] = math.nan, rate
    else:
        cm[REF_YAW], cm[REF_YAW_RATE] = cm[HOLD_YAW], 0.0
    cm[YAW_REF] = cm[HOLD_YAW]


@jit
def _manual_vertical(cm: np.ndarray) -> None:
    """ALTCTL's and POSCTL's vertical reference: the throttle stick's climb rate (:func:`autopilot.manual.climb_rate`
    of the shaped stick); centred, the altitude where the vehicle stops held, as an offboard climb rate of zero."""
    t = manual.expo_deadzone(cm[STICK_THROTTLE], cm[Z_EXPO], cm[HOLD_DZ])
    if t == 0.0:
        if math.isnan(cm[ALT_LOCK]):
            cm[ALT_LOCK] = max(cm[ALTITUDE] + stop_distance(cm[CLIMB_RATE], cm[ACC_HOR]), 0.0)
        cm[REF_ALT], cm[REF_CLIMB] = cm[ALT_LOCK], 0.0
    else:
        cm[ALT_LOCK] = math.nan
        cm[REF_ALT], cm[REF_CLIMB] = math.nan, manual.climb_rate(t, cm[Z_VEL_UP], cm[Z_VEL_DN])
    cm[REF_CLIMB_ACC] = math.nan


@jit
def _fly_manual(cm: np.ndarray, dt: float) -> None:
    """The manual modes' reference from the sticks (module docstring, :mod:`autopilot.manual`)."""
    mode = cm[MODE]
    cm[REF_THRUST], cm[REF_THROTTLE] = math.nan, math.nan
    if mode == STABILIZED:  # the sticks as they are: attitude, yaw rate, thrust (PX4's mc_att_control)
        cm[REF_ROLL], cm[REF_PITCH] = manual.tilt(cm[STICK_ROLL], cm[STICK_PITCH], cm[MAN_TILT])
        for i in range(REF_X, REF_CLIMB_ACC + 1):
            cm[i] = math.nan
        _manual_heading(cm, cm[STICK_YAW] * cm[MAN_YAW_RATE])
        cm[REF_LIMITED], cm[REF_THROTTLE] = 0.0, cm[STICK_THROTTLE]  # manual.throttle_curve keeps it within ±1
        return
    dz = cm[HOLD_DZ]
    pitch = manual.expo_deadzone(cm[STICK_PITCH], cm[XY_EXPO], dz)
    roll = manual.expo_deadzone(cm[STICK_ROLL], cm[XY_EXPO], dz)
    _manual_vertical(cm)
    _manual_heading(cm, manual.expo_deadzone(cm[STICK_YAW], cm[YAW_EXPO], dz) * cm[MAN_YAW_RATE])
    cm[REF_LIMITED] = 1.0
    if mode == ALTCTL:
        cm[REF_ROLL], cm[REF_PITCH] = manual.tilt(roll, pitch, cm[MAN_TILT])
        for i in range(REF_X, REF_AY + 1):
            cm[i] = math.nan
        return
    # POSCTL: the velocity reference goes toward the sticks' at up to MPC_ACC_HOR; at rest with the sticks centred,
    # the position where the vehicle stops is held
    cm[REF_ROLL], cm[REF_PITCH] = 0.0, 0.0
    want_n, want_e = manual.velocity(pitch, roll, cm[YAW], cm[VEL_MANUAL])
    dvx, dvy = want_n - cm[GEN_VX], want_e - cm[GEN_VY]
    n, dv_max = math.sqrt(dvx * dvx + dvy * dvy), cm[ACC_HOR] * dt
    if n > dv_max:
        dvx, dvy = dvx * dv_max / n, dvy * dv_max / n
    cm[GEN_VX] += dvx
    cm[GEN_VY] += dvy
    cm[GEN_AX], cm[GEN_AY] = (dvx / dt, dvy / dt) if dt > 0.0 else (0.0, 0.0)
    if cm[GEN_VX] == 0.0 and cm[GEN_VY] == 0.0 and pitch == 0.0 and roll == 0.0:
        if math.isnan(cm[POS_LOCK_X]):
            cm[POS_LOCK_X] = cm[X] + stop_distance(cm[VX], cm[ACC_HOR])
            cm[POS_LOCK_Y] = cm[Y] + stop_distance(cm[VY], cm[ACC_HOR])
        cm[REF_X], cm[REF_Y] = cm[POS_LOCK_X], cm[POS_LOCK_Y]
        for i in range(REF_VX, REF_AY + 1):
            cm[i] = 0.0
    else:
        cm[POS_LOCK_X], cm[POS_LOCK_Y] = math.nan, math.nan
        cm[REF_X], cm[REF_Y] = math.nan, math.nan
        cm[REF_VX], cm[REF_VY], cm[REF_AX], cm[REF_AY] = cm[GEN_VX], cm[GEN_VY], cm[GEN_AX], cm[GEN_AY]


@jit
def orbit_speed(radius: float, speed: float) -> float:
    """PX4's orbit speed [m/s, signed] on ``radius`` [m]: within ±ORBIT_SPEED_MAX, and slow enough that the
    centripetal acceleration v²/r stays below ORBIT_ACC_MAX (the speed, not the radius, gives way)."""
    v = min(max(speed, -ORBIT_SPEED_MAX), ORBIT_SPEED_MAX)
    if v * v >= ORBIT_ACC_MAX * radius:
        v = math.copysign(math.sqrt(ORBIT_ACC_MAX * radius), v)
    return v


@jit
def _orbit(cm: np.ndarray, dt: float) -> int:
    """ORBIT's reference, PX4's ``FlightTaskOrbit``: first to the nearest point of the circle (the auto modes'
    reference at MPC_XY_CRUISE, facing the centre); on it, a velocity along the circle (its speed slewing at
    MPC_ACC_HOR toward the orbit's), plus the radius' error, with the centripetal acceleration fed forward, at the
    centre's altitude; the heading as ORBIT_YAW_MODE says. Live sticks adjust it as PX4's: the pitch stick the radius
    (at MPC_XY_CRUISE), the roll stick the speed (at MPC_ACC_HOR; along the circle with the tangent heading: the other
    way round), the throttle the altitude (ALTCTL's), the yaw stick the heading in mode 4. → EVENT_ORBITS_DONE when
    the turns asked for are flown (then HOLD), else EVENT_NONE."""
    dx, dy = cm[X] - cm[ORBIT_X], cm[Y] - cm[ORBIT_Y]
    n = math.sqrt(dx * dx + dy * dy)
    ux, uy = (dx / n, dy / n) if n > 1e-6 else (1.0, 0.0)  # from the centre to the vehicle (north at the centre)
    r = cm[ORBIT_R]
    if cm[ORBIT_APPROACH] != 0.0:
        if abs(n - r) >= ORBIT_ON_CIRCLE or abs(cm[ALTITUDE] - cm[ORBIT_ALT]) >= ORBIT_ON_ALT:
            cm[TARGET_X], cm[TARGET_Y] = cm[ORBIT_X] + ux * r, cm[ORBIT_Y] + uy * r
            cm[TARGET_ALT] = cm[ORBIT_ALT]
            advance_reference(cm, dt, cm[LEG_SPEED], cm[Z_VEL_UP], cm[Z_VEL_DN])
            cm[HOLD_YAW] = math.atan2(-uy, -ux)
            _fly_generated(cm, dt)
            return EVENT_NONE
        cm[ORBIT_APPROACH], cm[ORBIT_SPEED], cm[ALT_LOCK] = 0.0, 0.0, cm[ORBIT_ALT]
    live = sticks_fresh(cm)
    mode = int(cm[ORBIT_YAW_MODE])
    v = cm[ORBIT_V]
    if live:
        pitch = manual.expo_deadzone(cm[STICK_PITCH], cm[XY_EXPO], cm[HOLD_DZ])
        roll = manual.expo_deadzone(cm[STICK_ROLL], cm[XY_EXPO], cm[HOLD_DZ])
        if mode == 3:
            way = 1.0 if cm[ORBIT_V] > 0.0 else -1.0
            r -= way * roll * dt * cm[CRUISE]
            v += way * pitch * dt * cm[ACC_HOR]
        else:
            r -= pitch * dt * cm[CRUISE]
            v -= roll * dt * cm[ACC_HOR]
        r = min(max(r, ORBIT_RADIUS_MIN), cm[ORBIT_RAD_MAX])
        cm[ORBIT_R], cm[ORBIT_V] = r, orbit_speed(r, v)
        v = cm[ORBIT_V]
    step = cm[ACC_HOR] * dt
    speed = cm[ORBIT_SPEED] + min(max(v - cm[ORBIT_SPEED], -step), step)
    cm[ORBIT_SPEED] = speed
    radial = r - n  # back onto the circle
    cm[REF_X], cm[REF_Y] = math.nan, math.nan
    cm[REF_VX], cm[REF_VY] = -uy * speed + radial * ux, ux * speed + radial * uy
    cm[REF_AX], cm[REF_AY] = -ux * speed * speed / r, -uy * speed * speed / r
    if live:
        _manual_vertical(cm)
    else:
        cm[REF_ALT], cm[REF_CLIMB], cm[REF_CLIMB_ACC] = cm[ALT_LOCK], 0.0, math.nan
    rate = speed / r  # the heading's turn around the circle, fed forward
    if mode == 1:
        turn_heading(cm, cm[ORBIT_HEADING], cm[YAW_RATE_AUTO], dt)
    elif mode == 2:
        cm[REF_YAW], cm[REF_YAW_RATE] = math.nan, 0.0
    elif mode == 4:
        yaw = manual.expo_deadzone(cm[STICK_YAW], cm[YAW_EXPO], cm[HOLD_DZ]) if live else 0.0
        _manual_heading(cm, yaw * cm[MAN_YAW_RATE])
    else:
        way = 1.0 if v > 0.0 else -1.0
        wanted = math.atan2(way * ux, -way * uy) if mode == 3 else math.atan2(-uy, -ux)
        turn_heading(cm, wanted, cm[YAW_RATE_AUTO] + abs(rate), dt)
        cm[REF_YAW_RATE] = rate
    cm[REF_ROLL], cm[REF_PITCH], cm[REF_LIMITED], cm[REF_THRUST] = 0.0, 0.0, 1.0, math.nan
    cm[ORBIT_ANGLE] += abs(speed) * dt / r
    if cm[ORBIT_TURNS] > 0.0 and cm[ORBIT_ANGLE] >= 2.0 * math.pi * cm[ORBIT_TURNS]:
        enter(cm, HOLD)
        return EVENT_ORBITS_DONE
    return EVENT_NONE


@jit
def target_fresh(cm: np.ndarray) -> bool:
    """Whether follow-me's target is reporting: its newest FOLLOW_TARGET within FOLLOW_TIMEOUT of simulated or of wall
    time."""
    return cm[NOW] - cm[TGT_TIME] <= FOLLOW_TIMEOUT or cm[TGT_WALL_FRESH] == 1.0


@jit
def _follow(cm: np.ndarray, dt: float) -> int:
    """FOLLOW's reference, PX4's ``FlightTaskAutoFollowTarget``: the target (predicted from its newest report with its
    velocity) seen from FLW_TGT_DST away at the angle its course plus FLW_TGT_FA, FLW_TGT_HT above home, the ground
    or the target (FLW_TGT_ALT_M; never below FOLLOW_SAFETY_ALT), flying the target's velocity too and facing it. The
    angle around the target turns toward its side at up to FLW_TGT_MAX_VEL along the circle (FOLLOW_ACC to speed
    up and slow down); while far from its height it climbs or descends first, where it is. No report for
    FOLLOW_TIMEOUT: it stops and holds → EVENT_TARGET_LOST; reports again → EVENT_TARGET_BACK."""
    if not target_fresh(cm):
        event = EVENT_NONE
        if cm[TGT_LOST] == 0.0:
            event = EVENT_TARGET_LOST
            cm[TGT_LOST] = 1.0
            start_here(cm)
            cm[HOLD_YAW] = cm[YAW_REF]
        advance_reference(cm, dt, cm[CRUISE], cm[Z_VEL_UP], cm[Z_VEL_DN])
        _fly_generated(cm, dt)
        return event
    event = EVENT_NONE
    if cm[TGT_LOST] != 0.0:
        cm[TGT_LOST] = 0.0
        event = EVENT_TARGET_BACK
    age = cm[NOW] - cm[TGT_TIME]
    tx, ty = cm[TGT_X] + cm[TGT_VX] * age, cm[TGT_Y] + cm[TGT_VY] * age
    if math.sqrt(cm[TGT_VX] ** 2 + cm[TGT_VY] ** 2) >= FOLLOW_COURSE_SPEED:
        cm[TGT_COURSE] = math.atan2(cm[TGT_VY], cm[TGT_VX])
    # the angle around the target: toward its side the short way, the rate as a bounded trajectory
    d = cm[FLW_DST]
    error = wrap_pi(cm[TGT_COURSE] + cm[FLW_FA] - cm[FOLLOW_ANGLE])
    rate_max, acc = cm[FLW_MAX_VEL] / d, FOLLOW_ACC / d
    want = math.copysign(min(math.sqrt(2.0 * acc * abs(error)), rate_max), error)
    rate = cm[FOLLOW_RATE] + min(max(want - cm[FOLLOW_RATE], -acc * dt), acc * dt)
    if abs(error) <= abs(rate) * dt:
        cm[FOLLOW_ANGLE], rate = cm[TGT_COURSE] + cm[FLW_FA], 0.0
    else:
        cm[FOLLOW_ANGLE] = wrap_pi(cm[FOLLOW_ANGLE] + rate * dt)
    cm[FOLLOW_RATE] = rate
    a = cm[FOLLOW_ANGLE]
    mode = cm[FLW_ALT_M]
    base = cm[HOME_ALT] if mode == 0.0 else 0.0 if mode == 1.0 else cm[TGT_ALT] + cm[TGT_CLIMB] * age
    altitude = max(base + cm[FLW_HT], FOLLOW_SAFETY_ALT)
    if abs(altitude - cm[ALTITUDE]) >= FOLLOW_ALT_FIRST:  # the height first, where it is
        cm[REF_X], cm[REF_Y] = cm[X], cm[Y]
        for i in range(REF_VX, REF_AY + 1):
            cm[i] = 0.0
    else:
        cm[REF_X], cm[REF_Y] = tx + d * math.cos(a), ty + d * math.sin(a)
        cm[REF_VX] = cm[TGT_VX] - math.sin(a) * rate * d
        cm[REF_VY] = cm[TGT_VY] + math.cos(a) * rate * d
        cm[REF_AX], cm[REF_AY] = 0.0, 0.0
    cm[REF_ALT], cm[REF_CLIMB], cm[REF_CLIMB_ACC] = altitude, 0.0, math.nan
    dx, dy = tx - cm[X], ty - cm[Y]
    if dx * dx + dy * dy > FOLLOW_YAW_DISTANCE**2:
        cm[HOLD_YAW] = math.atan2(dy, dx)
    turn_heading(cm, cm[HOLD_YAW], cm[YAW_RATE_AUTO], dt)
    cm[REF_ROLL], cm[REF_PITCH], cm[REF_LIMITED], cm[REF_THRUST] = 0.0, 0.0, 1.0, math.nan
    return event


@jit
def update(
    cm: np.ndarray, tick: int, now: float, x: float, y: float, altitude: float, vx: float, vy: float,
    climb_rate: float, yaw: float,
) -> int:  # fmt: skip
    """Advance to tick ``tick`` at simulated time ``now`` [s] with the measured position (x, y NED, altitude
    up) [m], velocity (vx, vy NED, climb rate up) [m/s] and yaw [rad]. While armed afterwards, the reference group
    (cm[REFERENCE_FIRST:REFERENCE_END]) is the reference to fly. Returns an EVENT_* for the shell to announce."""
    dt = max(now - cm[NOW], 0.0)
    cm[TICK], cm[NOW], cm[X], cm[Y], cm[ALTITUDE] = tick, now, x, y, altitude
    cm[VX], cm[VY], cm[CLIMB_RATE], cm[YAW] = vx, vy, climb_rate, yaw
    battery = _battery(cm)
    sticks = _sticks(cm)
    if cm[ARMED] == 0.0:
        return sticks  # the sticks' return is said on the ground too; their loss does nothing there
    if sticks == EVENT_STICKS_LOST and cm[STICK_ACTION] >= 5.0:  # terminated or disarmed
        return sticks
    event = auto_disarm(cm, now)
    if event != EVENT_NONE:
        return event
    if cm[GF_ACTION] != 0.0:  # GF_ACTION none: not checked, as PX4
        event = _geofence(cm)
        if cm[ARMED] == 0.0:  # terminated
            return event
    if event == EVENT_NONE:
        event = battery
    if event == EVENT_NONE:
        event = sticks
    mode = cm[MODE]
    if mode == OFFBOARD and cm[OFFBOARD_TICK] < 0.0:
        cm[OFFBOARD_TICK] = tick
    if mode == OFFBOARD and not stream_fresh(cm):
        cm[FAILSAFE] = FAILSAFE_SETPOINT_LOST
        event = EVENT_SETPOINT_LOST
        enter(cm, LAND)
        mode = LAND
    if mode == OFFBOARD:
        _fly_offboard(cm, dt)
        return event
    if mode in (POSCTL, ALTCTL, STABILIZED):
        _fly_manual(cm, dt)
        return event
    if mode == ORBIT:
        done = _orbit(cm, dt)
        return done if done != EVENT_NONE else event
    if mode == FOLLOW:
        said = _follow(cm, dt)
        return said if said != EVENT_NONE else event
    if mode == LAND:
        landed = _land(cm, dt, now)
        return landed if landed != EVENT_NONE else event
    if mode == RTL:
        if cm[PHASE] == RTL_LAND:
            return _land(cm, dt, now)
        done = advance_reference(cm, dt, cm[LEG_SPEED], cm[Z_VEL_UP], cm[Z_VEL_DN])
        if done and cm[PHASE] == RTL_CLIMB:
            cm[PHASE] = RTL_RETURN
            cm[TARGET_X], cm[TARGET_Y] = cm[RTL_X], cm[RTL_Y]  # home, or the rally point nearer
        elif done and cm[PHASE] == RTL_RETURN:
            cm[PHASE] = RTL_LAND
            cm[LAND_ALT] = cm[GEN_ALT]
            event = EVENT_HOME_REACHED
        _fly_generated(cm, dt)
        return event
    if mode == TAKEOFF:
        done = advance_reference(cm, dt, cm[LEG_SPEED], cm[TKO_SPEED], cm[Z_VEL_DN])
        _fly_generated(cm, dt)
        if done and abs(altitude - cm[TARGET_ALT]) < TAKEOFF_TOLERANCE:
            cm[MODE] = HOLD  # the reference rests on the target: hold it
            return EVENT_TAKEOFF_DONE
        return event
    # HOLD and MISSION: the leg's vertical speeds (a mission's takeoff, DO_CHANGE_SPEED) within MPC_Z_VEL_MAX_UP, _DN
    up = cm[Z_VEL_UP] if math.isnan(cm[LEG_CLIMB]) else min(cm[LEG_CLIMB], cm[Z_VEL_UP])
    down = cm[Z_VEL_DN] if math.isnan(cm[LEG_DESCENT]) else min(cm[LEG_DESCENT], cm[Z_VEL_DN])
    advance_reference(cm, dt, cm[LEG_SPEED], up, down)
    _fly_generated(cm, dt)
    return event


class Commander:
    """The modes, arming, setpoints and failsafes of one vehicle (see the module's docstring): events are
    methods, the tick is :meth:`update` (or :func:`update` on ``self.cm`` from compiled code)."""

    def __init__(self, settings: CommanderSettings | None = None) -> None:
        self.cm = np.zeros(geofence.CM_SIZE)  # the state declared, then the geofence's items
        self.cm[SETPOINT_FIRST:SETPOINT_END] = math.nan
        self.cm[[LANDED_SINCE, TAKEOFF_ALT, ALT_LOCK, RESTING_SINCE]] = math.nan
        self.cm[REFERENCE_FIRST:REFERENCE_END] = math.nan
        self.cm[LAST_SP_TIME] = -1e9
        self.cm[OFFBOARD_TICK] = -1.0
        self.cm[BAT_V : BAT_REMAINING + 1] = math.nan  # no battery until one reports
        self.cm[STICK_TIME], self.cm[STICK_LOST] = -1e9, STICKS_NEVER
        self.cm[TGT_TIME] = -1e9  # no follow-me target yet
        self.cm[[POS_LOCK_X, POS_LOCK_Y, STICK_DEADLINE]] = math.nan
        self.settings = settings or CommanderSettings()
        self.messages: list[tuple[int, str]] = []  # (MAV_SEVERITY, text) to announce
        self.setpoint_wall = -math.inf  # [s] the shell's wall clock when the newest setpoint arrived
        self.sticks_wall = -math.inf  # [s] the shell's wall clock when the newest sticks arrived
        self.target_wall = -math.inf  # [s] the shell's wall clock when the newest FOLLOW_TARGET arrived
        self.armed_wall: float | None = None  # [s] the shell's wall clock at its first call after arming

    # ---- the state, by name --------------------------------------------------------------------

    @property
    def settings(self) -> CommanderSettings:
        return self._settings

    @settings.setter
    def settings(self, settings: CommanderSettings) -> None:
        self._settings = settings
        cm, s = self.cm, settings
        cm[SETPOINT_TIMEOUT], cm[LAND_SPEED], cm[LANDED_TIME], cm[LAND_TARGET] = (
            s.setpoint_timeout, s.land_speed, s.landed_time, s.land_target,
        )  # fmt: skip
        cm[ACC_HOR], cm[CRUISE], cm[TKO_SPEED] = s.acc_hor, s.cruise, s.takeoff_speed
        cm[Z_VEL_UP], cm[Z_VEL_DN], cm[RTL_ALT] = s.z_vel_up, s.z_vel_dn, s.rtl_alt
        cm[YAW_RATE_AUTO], cm[YAW_RATE_OFFBOARD] = s.yaw_rate_auto, s.yaw_rate_offboard
        cm[DISARM_PREFLIGHT] = s.disarm_preflight
        cm[GF_ACTION], cm[GF_MAX_HOR], cm[GF_MAX_VER] = s.geofence_action, s.max_distance, s.max_height
        cm[BAT_LOW], cm[BAT_CRIT], cm[BAT_EMERGEN] = s.bat_low_thr, s.bat_crit_thr, s.bat_emergen_thr
        cm[BAT_ACTION] = s.low_bat_action
        cm[RC_LOSS_T], cm[RCL_ACT], cm[RCL_EXCEPT], cm[RC_IN_MODE] = (
            s.rc_loss_timeout, s.rc_loss_action, s.rc_loss_except, s.rc_in_mode,
        )  # fmt: skip
        cm[MAN_TILT], cm[MAN_YAW_RATE], cm[VEL_MANUAL] = s.man_tilt_max, s.man_yaw_rate, s.vel_manual
        cm[HOLD_DZ], cm[XY_EXPO], cm[Z_EXPO], cm[YAW_EXPO] = s.hold_deadzone, s.xy_expo, s.z_expo, s.yaw_expo
        cm[FAIL_ACT_T] = s.fail_act_t
        cm[ORBIT_RAD_MAX], cm[ORBIT_YAW_DEFAULT] = s.orbit_radius_max, s.orbit_yaw_mode
        cm[FLW_HT], cm[FLW_DST], cm[FLW_FA] = s.follow_height, s.follow_distance, s.follow_angle
        cm[FLW_ALT_M], cm[FLW_MAX_VEL], cm[FLW_RS] = s.follow_altitude_mode, s.follow_max_speed, s.follow_responsiveness

    @property
    def armed(self) -> bool:
        return bool(self.cm[ARMED])

    @property
    def mode(self) -> Mode:
        return Mode(int(self.cm[MODE]))

    @property
    def failsafe(self) -> int:
        return int(self.cm[FAILSAFE])

    @property
    def offboard_tick(self) -> int:
        return int(self.cm[OFFBOARD_TICK])

    @property
    def now(self) -> float:
        return float(self.cm[NOW])

    @property
    def last_setpoint_time(self) -> float:
        return float(self.cm[LAST_SP_TIME])

    @last_setpoint_time.setter
    def last_setpoint_time(self, t: float) -> None:
        self.cm[LAST_SP_TIME] = t

    @property
    def altitude_setpoint(self) -> float | None:
        return None if math.isnan(self.cm[SP_ALT]) else float(self.cm[SP_ALT])

    @property
    def attitude_setpoint(self) -> tuple[float, float, float] | None:
        """(roll, pitch, yaw) [rad] of the last attitude setpoint; None before the first."""
        return None if math.isnan(self.cm[ROLL_SP]) else tuple(self.cm[ROLL_SP : YAW_SP + 1].tolist())

    @property
    def home(self) -> tuple[float, float, float]:
        """Home: where the vehicle last armed (x, y NED [m], altitude [m]); the origin before it has."""
        return float(self.cm[HOME_X]), float(self.cm[HOME_Y]), float(self.cm[HOME_ALT])

    @property
    def home_yaw(self) -> float:
        """The heading at arming [rad]."""
        return float(self.cm[HOME_YAW])

    @property
    def position_target(self) -> tuple[float, float, float]:
        """The position the auto modes are heading for: (x, y NED [m], altitude [m])."""
        return float(self.cm[TARGET_X]), float(self.cm[TARGET_Y]), float(self.cm[TARGET_ALT])

    @property
    def reference(self) -> Reference:
        """The altitude and attitude reference of the last tick (valid while armed): roll and pitch are the
        attitude setpoint's (0 where the position loop makes them); the altitude is NaN while a climb rate
        alone is flown, the yaw NaN while a yaw rate alone is."""
        cm = self.cm
        return Reference(float(cm[REF_ALT]), float(cm[REF_ROLL]), float(cm[REF_PITCH]), float(cm[REF_YAW]))

    @property
    def landing(self) -> bool:
        """Descending to land (LAND, or RTL's last phase)."""
        return self.mode == Mode.LAND or (self.mode == Mode.RTL and self.cm[PHASE] == RTL_LAND)

    # ---- events --------------------------------------------------------------------------------

    def stream_fresh(self) -> bool:
        return bool(stream_fresh(self.cm))

    def wall_clock(self, wall: float) -> None:
        """The shell's wall clock [s], every few milliseconds: the setpoint stream stays fresh while its newest
        setpoint arrived (``wall=`` of the setpoint handlers) within the timeout of wall time too."""
        self.cm[SP_WALL_FRESH] = 1.0 if wall - self.setpoint_wall <= self.settings.setpoint_timeout else 0.0
        self.cm[STICK_WALL_FRESH] = 1.0 if wall - self.sticks_wall <= self.settings.rc_loss_timeout else 0.0
        self.cm[TGT_WALL_FRESH] = 1.0 if wall - self.target_wall <= FOLLOW_TIMEOUT else 0.0
        if not self.armed:
            self.armed_wall = None
            return
        if self.armed_wall is None:
            self.armed_wall = wall
        self.cm[ARM_WALL_RECENT] = 1.0 if wall - self.armed_wall < self.settings.disarm_preflight else 0.0

    def on_attitude_setpoint(
        self, roll: float | None, pitch: float | None, yaw: float | None, wall: float = -math.inf,
        thrust: float = math.nan,
    ) -> None:  # fmt: skip
        """A SET_ATTITUDE_TARGET (None for an axis the type_mask ignores): roll and pitch take over the
        horizontal axes from any position, velocity or acceleration setpoint; a ``thrust`` (normalised collective,
        NaN: ignored) takes over the vertical axis from any altitude or climb rate, until one comes again.
        ``wall``: the shell's wall clock [s] (see :meth:`wall_clock`)."""
        old = self.attitude_setpoint or (0.0, 0.0, float(self.cm[YAW]))
        cm = self.cm
        if not math.isnan(thrust):
            cm[SP_ALT], cm[SP_CLIMB], cm[SP_CLIMB_ACC], cm[SP_THRUST] = math.nan, math.nan, math.nan, thrust
        cm[ROLL_SP] = old[0] if roll is None else roll
        cm[PITCH_SP] = old[1] if pitch is None else pitch
        cm[YAW_SP] = old[2] if yaw is None else yaw
        cm[SP_YAW_RATE] = math.nan
        cm[SP_HORIZONTAL_FIRST:SP_HORIZONTAL_END] = math.nan
        cm[LAST_SP_TIME] = cm[NOW]
        self.setpoint_wall = max(self.setpoint_wall, wall)

    def on_altitude_setpoint(self, altitude: float | None, wall: float = -math.inf) -> None:
        """An altitude alone (None: nothing but a sign of life for the stream)."""
        nan = math.nan
        self.on_position_setpoint(vertical=None if altitude is None else (altitude, nan, nan), wall=wall)

    def on_position_setpoint(
        self,
        horizontal: tuple[float, float, float, float, float, float] | None = None,
        vertical: tuple[float, float, float] | None = None,
        heading: tuple[float, float] | None = None,
        wall: float = -math.inf,
    ) -> None:
        """A SET_POSITION_TARGET_*, already validated and in local NED: ``horizontal`` (x, y, vx, vy, ax, ay),
        ``vertical`` (altitude, climb rate, its rate), ``heading`` (yaw, yaw rate), NaN for a field the
        type_mask ignores; None for a group whose fields are all ignored (it stays as it was). Any setpoint
        counts for the stream. ``wall``: the shell's wall clock [s] (see :meth:`wall_clock`)."""
        cm = self.cm
        if horizontal is not None:
            cm[SP_HORIZONTAL_FIRST:SP_HORIZONTAL_END] = horizontal
        if vertical is not None:
            cm[SP_ALT], cm[SP_CLIMB], cm[SP_CLIMB_ACC] = vertical
            cm[SP_THRUST] = math.nan
        if heading is not None:
            cm[YAW_SP], cm[SP_YAW_RATE] = heading
        elif horizontal is not None and not math.isnan(cm[SP_YAW_RATE]):
            cm[YAW_SP], cm[SP_YAW_RATE] = cm[YAW], math.nan  # a new setpoint without a yaw rate stops turning
        cm[LAST_SP_TIME] = cm[NOW]
        self.setpoint_wall = max(self.setpoint_wall, wall)

    def on_sticks(self, pitch: float, roll: float, throttle: float, yaw: float, wall: float = -math.inf) -> None:
        """MANUAL_CONTROL's sticks, as PX4's manual_control_setpoint (each −1..1; throttle −1 at the bottom), checked
        by the receiver: flown by the manual modes, and a sign of life for the sticks' loss. Not taken when
        COM_RC_IN_MODE says there is no MAVLink stick input (0: RC only; 4: disabled). ``wall``: the shell's wall
        clock [s] (see :meth:`wall_clock`)."""
        if self.settings.rc_in_mode in (0, RC_IN_MODE_DISABLED):
            return
        cm = self.cm
        cm[STICK_PITCH], cm[STICK_ROLL], cm[STICK_THROTTLE], cm[STICK_YAW] = pitch, roll, throttle, yaw
        cm[STICK_TIME] = cm[NOW]
        self.sticks_wall = max(self.sticks_wall, wall)

    def on_manual_control(self, r: ManualControl) -> None:
        """Sticks from the receiver (:mod:`autopilot.receiver`)."""
        self.on_sticks(r.pitch, r.roll, r.throttle, r.yaw, wall=r.wall)

    def on_follow_target(self, r: FollowTarget) -> None:
        """A FOLLOW_TARGET from the receiver: follow-me's target, filtered as PX4's target estimator does in spirit
        (an α filter of gain 1 − FLW_TGT_RS: the report predicted with the velocity, then corrected toward it; the
        velocity toward the report's, or, without one, toward the change between reports). The first, or one after
        the target was lost, is taken as it is."""
        cm = self.cm
        dt = max(cm[NOW] - cm[TGT_TIME], 0.0)
        vx, vy, climb = r.vx, r.vy, r.climb
        continuing = cm[TGT_TIME] > -1e8 and (dt <= FOLLOW_TIMEOUT or r.wall - self.target_wall <= FOLLOW_TIMEOUT)
        if continuing:
            g = 1.0 - self.settings.follow_responsiveness
            px, py = cm[TGT_X] + cm[TGT_VX] * dt, cm[TGT_Y] + cm[TGT_VY] * dt
            palt = cm[TGT_ALT] + cm[TGT_CLIMB] * dt
            if math.isnan(vx):  # no velocity reported: the change since the last report (none within a tick)
                vx, vy, climb = cm[TGT_VX], cm[TGT_VY], cm[TGT_CLIMB]
                if dt > 0.0:
                    vx, vy, climb = (r.x - cm[TGT_X]) / dt, (r.y - cm[TGT_Y]) / dt, (r.altitude - cm[TGT_ALT]) / dt
            x, y, altitude = px + g * (r.x - px), py + g * (r.y - py), palt + g * (r.altitude - palt)
            vx, vy, climb = (cm[TGT_VX] + g * (vx - cm[TGT_VX]), cm[TGT_VY] + g * (vy - cm[TGT_VY]),
                             cm[TGT_CLIMB] + g * (climb - cm[TGT_CLIMB]))  # fmt: skip
        else:
            x, y, altitude = r.x, r.y, r.altitude
            if math.isnan(vx):
                vx = vy = climb = 0.0
        cm[TGT_X], cm[TGT_Y], cm[TGT_ALT], cm[TGT_VX], cm[TGT_VY], cm[TGT_CLIMB] = x, y, altitude, vx, vy, climb
        cm[TGT_TIME] = cm[NOW]
        self.target_wall = max(self.target_wall, r.wall)

    def sticks_fresh(self) -> bool:
        return bool(sticks_fresh(self.cm))

    def on_trajectory(self, r: TrajectorySetpoint) -> None:
        """A trajectory setpoint from the receiver (:mod:`autopilot.receiver`)."""
        self.on_position_setpoint(r.horizontal, r.vertical, r.heading, wall=r.wall)

    def on_attitude(self, r: AttitudeSetpoint) -> None:
        """An attitude setpoint from the receiver."""
        self.on_attitude_setpoint(r.roll, r.pitch, r.yaw, wall=r.wall, thrust=r.thrust)

    def arm(self) -> tuple[bool, str]:
        if self.armed:
            return True, ""
        if self.mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Arming denied: no offboard setpoint stream"
        if self.mode in (Mode.LAND, Mode.RTL):
            return False, f"Arming denied: mode {self.mode.name.lower()}; switch to hold, takeoff or offboard"
        if self.settings.geofence_action != 0 and geofence.fence_breach(self.cm, self.cm[X], self.cm[Y]):
            return False, "Arming denied: vehicle outside the geofence"
        if battery_level(self.cm) >= 2:
            return False, (f"Arming denied: low battery, {self.cm[BAT_REMAINING]:.0%} remaining "
                           f"(BAT_CRIT_THR {self.settings.bat_crit_thr:.0%})")  # fmt: skip
        if self.mode in MANUAL_MODES:
            reason = self._manual_arming_check()
            if reason:
                return False, reason
        arm(self.cm)
        self.messages.append((6, "Armed"))
        return True, ""

    def flying(self) -> bool:
        """Armed and off the ground (what goto, orbit and follow-me need)."""
        return self.armed and self.cm[ALTITUDE] >= TOUCHDOWN_ALT + 0.1

    def _manual_arming_check(self) -> str:
        """PX4's checks for arming in a manual mode: the sticks live; the throttle not above the centre (ALTCTL,
        POSCTL: it would climb at once), or low (STABILIZED: it is the thrust). "" when they pass."""
        if not self.sticks_fresh():
            return f"Arming denied: no manual control input (MANUAL_CONTROL) for {self.mode.name.lower()}"
        throttle = self.cm[STICK_THROTTLE]
        if self.mode == Mode.STABILIZED and throttle >= THROTTLE_LOW:
            return f"Arming denied: high throttle ({throttle:+.2f}; below {THROTTLE_LOW:+.1f} to arm in stabilized)"
        if self.mode != Mode.STABILIZED and throttle > THROTTLE_ABOVE_CENTER:
            return f"Arming denied: throttle above center ({throttle:+.2f}; at most {THROTTLE_ABOVE_CENTER:+.1f})"
        return ""

    def disarm(self, reason: str = "Disarmed") -> None:
        if self.armed:
            self.cm[ARMED] = 0.0
            self.cm[OFFBOARD_TICK] = -1.0
            self.messages.append((6, reason))

    def takeoff(self, altitude: float | None = None) -> tuple[bool, str]:
        """MAV_CMD_NAV_TAKEOFF: climb to ``altitude`` [m above the local ground] (None: the current altitude
        plus MIS_TAKEOFF_ALT) and hold there. Accepted while disarmed (the takeoff starts on arming)."""
        cm = self.cm
        if self.armed and cm[ALTITUDE] > TOUCHDOWN_ALT + 0.1 and self.mode != Mode.TAKEOFF:
            return False, "Takeoff denied: already flying"
        target = max(cm[ALTITUDE], 0.0) + self.settings.takeoff_alt if altitude is None else altitude
        if not 0.0 < target <= self.settings.altitude_max:
            return False, f"Takeoff denied: altitude {target:g} m; allowed: (0, {self.settings.altitude_max:g}] m"
        cm[TAKEOFF_ALT] = target
        enter(cm, TAKEOFF)
        self.messages.append((6, f"Taking off to {target:.1f} m"))
        return True, ""

    def reposition(self, x: float, y: float, altitude: float, yaw: float, speed: float, hold: bool) -> tuple[bool, str]:
        """MAV_CMD_DO_REPOSITION (MAVSDK's goto): fly to (x, y NED [m], altitude [m]) at ``speed`` [m/s] (NaN:
        MPC_XY_CRUISE), heading ``yaw`` [rad]; NaN keeps the current target's value. ``hold``: switch to hold
        first (param2 bit 0); without it the vehicle must be in hold already."""
        cm = self.cm
        if not self.flying():
            return False, "Reposition denied: not flying (take off first)"
        if self.mode != Mode.HOLD:
            if not hold:
                return False, f"Reposition denied: mode {self.mode.name.lower()} (set param2 bit 0 to switch to hold)"
            enter(cm, HOLD)
            self.messages.append((6, "Mode hold"))
        self.goto(x, y, altitude, yaw, speed)
        return True, ""

    def outside_fence(self, x: float, y: float, altitude: float) -> bool:
        """Whether a reposition or an orbit to (x, y NED [m], altitude [m]; NaN: the vehicle's) is outside the geofence
        while a breach would be acted on (GF_ACTION beyond a warning): PX4's navigator then ignores it."""
        if self.settings.geofence_action in (0, 1):
            return False
        cm = self.cm
        x, y = (cm[X] if math.isnan(x) else x), (cm[Y] if math.isnan(y) else y)
        return geofence.point_breach(cm, x, y, cm[ALTITUDE] if math.isnan(altitude) else altitude) != 0

    def orbit(self, radius: float, speed: float, yaw_mode: float, turns: float, x: float, y: float,
              altitude: float) -> tuple[bool, str]:  # fmt: skip
        """MAV_CMD_DO_ORBIT, as PX4 takes it: circle (x, y NED [m], altitude [m]) on ``radius`` [m] (its sign the way
        round: positive clockwise seen from above) at ``speed`` [m/s] (its sign reverses the way), heading as
        ORBIT_YAW ``yaw_mode`` says (5: unchanged), ``turns`` times (0: for ever); NaN keeps a value (orbiting) or
        takes PX4's start (1 m, 1 m/s, MC_ORBIT_YAW_MOD, for ever, around the vehicle where it is). A speed too fast
        for the radius is slowed (:func:`orbit_speed`) and said. → (taken, why not)."""
        cm = self.cm
        if not self.flying():
            return False, "Orbit denied: not flying (take off first)"
        orbiting = self.mode == Mode.ORBIT
        r, v = (float(cm[ORBIT_R]), float(cm[ORBIT_V])) if orbiting else (ORBIT_RADIUS_MIN, 1.0)
        clockwise = v > 0.0
        if math.isfinite(radius):
            clockwise, r = radius > 0.0, abs(radius)
        if not ORBIT_RADIUS_MIN <= r <= self.settings.orbit_radius_max:
            return False, (f"Orbit denied: radius {r:g} m; allowed: [{ORBIT_RADIUS_MIN:g}, "
                           f"{self.settings.orbit_radius_max:g}] m (MC_ORBIT_RAD_MAX)")  # fmt: skip
        asked = math.copysign(abs(v) if math.isnan(speed) else speed, 1.0 if clockwise else -1.0)
        if math.isinf(asked):
            return False, f"Orbit denied: speed {speed:g} m/s; expected a number or NaN (keep)"
        mode = int(cm[ORBIT_YAW_MODE]) if orbiting else self.settings.orbit_yaw_mode
        if math.isfinite(yaw_mode) and round(yaw_mode) != ORBIT_YAW_UNCHANGED:
            if yaw_mode != round(yaw_mode) or not 0 <= yaw_mode < len(ORBIT_YAW):
                return False, (f"Orbit denied: yaw behaviour {yaw_mode:g}; allowed: 0..4 "
                               f"({', '.join(ORBIT_YAW)}) or 5 (unchanged)")  # fmt: skip
            mode = int(yaw_mode)
        if math.isnan(turns):
            turns = float(cm[ORBIT_TURNS]) if orbiting else 0.0
        elif not 0.0 <= turns < math.inf:
            return False, f"Orbit denied: orbits {turns:g}; allowed: 0 (for ever) or more"
        centre = (cm[ORBIT_X], cm[ORBIT_Y], cm[ORBIT_ALT]) if orbiting else (cm[X], cm[Y], cm[ALTITUDE])
        x, y, altitude = (c if math.isnan(w) else w for w, c in zip((x, y, altitude), centre, strict=True))
        v = orbit_speed(r, asked)
        cm[ORBIT_X], cm[ORBIT_Y], cm[ORBIT_ALT], cm[ORBIT_R], cm[ORBIT_V] = x, y, altitude, r, v
        cm[ORBIT_YAW_MODE], cm[ORBIT_HEADING], cm[ORBIT_TURNS] = mode, cm[YAW], turns
        if v != asked:
            self.messages.append((4, f"Orbit speed {abs(asked):g} m/s reduced to {abs(v):.2f} m/s: at most "
                                     f"{ORBIT_SPEED_MAX:g} m/s and {ORBIT_ACC_MAX:g} m/s² toward the centre on "
                                     f"{r:g} m"))  # fmt: skip
        if not orbiting:
            enter(cm, ORBIT)
        elif abs(math.hypot(cm[X] - x, cm[Y] - y) - r) >= ORBIT_ON_CIRCLE:  # PX4: to the circle again
            cm[ORBIT_APPROACH] = 1.0
            start_here(cm)  # the approach aims its target anew each tick
        cm[ORBIT_ANGLE] = 0.0
        way = "clockwise" if v > 0.0 else "counter-clockwise"
        self.messages.append((6, f"Orbit: {r:g} m {way} at {abs(v):.2f} m/s, heading {ORBIT_YAW[mode]}"
                                 + (f", {turns:g} turns" if turns else "")))  # fmt: skip
        return True, ""

    def goto(self, x: float, y: float, altitude: float, yaw: float, speed: float, climb: float = math.nan,
             descent: float = math.nan) -> None:  # fmt: skip
        """Aim the auto modes' reference at (x, y NED [m], altitude [m]), heading ``yaw`` [rad], at ``speed``
        [m/s] (NaN or ≤ 0: MPC_XY_CRUISE), climbing at up to ``climb`` and descending at up to ``descent`` [m/s]
        (NaN: MPC_Z_VEL_MAX_UP, _DN); NaN keeps a position or heading. No checks: :meth:`reposition` and the
        mission executor check first."""
        cm = self.cm
        for index, value in ((TARGET_X, x), (TARGET_Y, y), (TARGET_ALT, altitude), (HOLD_YAW, yaw)):
            if not math.isnan(value):
                cm[index] = value
        cm[LEG_SPEED] = self.settings.cruise if math.isnan(speed) or speed <= 0.0 else speed
        cm[LEG_CLIMB], cm[LEG_DESCENT] = climb, descent

    def position_target_here(self) -> tuple[float, float, float]:
        """Where the vehicle can stop from its current velocity (x, y NED [m], altitude [m])."""
        cm, a = self.cm, self.settings.acc_hor
        return (float(cm[X] + stop_distance(cm[VX], a)), float(cm[Y] + stop_distance(cm[VY], a)),
                float(max(cm[ALTITUDE] + stop_distance(cm[CLIMB_RATE], a), 0.0)))  # fmt: skip

    def change_speed(self, speed: float) -> None:
        """MAV_CMD_DO_CHANGE_SPEED: the horizontal speed of the current and later legs [m/s]."""
        self.settings.cruise = speed
        self.cm[CRUISE] = self.cm[LEG_SPEED] = speed

    def set_fence(self, fence: np.ndarray) -> None:
        """The geofence's polygons and circles (:func:`autopilot.geofence.items_to_array`), flown from the next tick."""
        geofence.set_fence(self.cm, fence)

    def set_rally(self, rally: np.ndarray) -> None:
        """The rally points (:func:`autopilot.geofence.rally_to_array`): a return from now on goes to the nearest of
        them and home."""
        geofence.set_rally(self.cm, rally)

    def plant_lost(self) -> None:
        """No vehicle state arrives: flying blind. Armed, switch to LAND (it resumes when states do)."""
        self._fail_and_land("Plant link lost: no vehicle state", FAILSAFE_PLANT_LOST)

    def estimator_failed(self, why: str = "Estimator diverged: innovations beyond their bound") -> None:
        """The state estimate is not to be trusted (sensor mode: the estimator diverged, or lost the GPS). Armed,
        switch to LAND, as PX4 does when its position estimate is lost."""
        self._fail_and_land(why, FAILSAFE_ESTIMATOR)

    def position_lost(self) -> None:
        """The horizontal position is lost (sensor mode: the GPS lost). Armed, the estimator failsafe as PX4 has it
        without a pilot: Descend, a landing that holds no position, level (:func:`_land`)."""
        self.cm[NO_POSITION] = 1.0 if self.armed else 0.0
        self._fail_and_land("Position estimate lost: no GPS; descending", FAILSAFE_ESTIMATOR)

    def _fail_and_land(self, why: str, failsafe: int) -> None:
        """Say ``why`` (critical); armed, the failsafe ``failsafe``: LAND."""
        self.messages.append((2, why))
        if self.armed:
            self.cm[FAILSAFE] = failsafe
            if self.mode != Mode.LAND:
                enter(self.cm, LAND)
                self.messages.append((2, "Failsafe: landing"))

    def datalink_lost(self, seconds: float) -> None:
        """No ground-station heartbeat for ``seconds``: the configured action (NAV_DLL_ACT)."""
        action = DATALINK_ACTIONS[self.settings.datalink_action]
        self.messages.append((2, f"Ground station lost: no heartbeat for {seconds:g} s; action: {action}"))
        if self.armed and action != "none":
            self.cm[FAILSAFE] = FAILSAFE_GCS_LOST
            mode = HOLD if action == "hold" else LAND
            if self.cm[MODE] != mode:
                enter(self.cm, mode)

    def motors_failed(self, off: int, what: str) -> None:
        """The motors now off (bits: motor i + 1 is 1 << i; a failure injected, ``what`` in words). One newly off
        while armed in the air is PX4's actuator failure: COM_ACT_FAIL_ACT's action (none, hold, land, return, or
        terminate: the motors off, the vehicle falls), said."""
        newly = off & ~int(self.cm[MOTORS_OFF])
        self.cm[MOTORS_OFF] = float(off)
        if not newly or not self.armed or self.cm[ALTITUDE] <= AIRBORNE_ALT:
            return
        action = ACTUATOR_FAILURE_ACTIONS[self.settings.actuator_failure_action]
        self.messages.append((2, f"Motor failure: {what}; action: {action}"))
        if action == "none":
            return
        self.cm[FAILSAFE] = FAILSAFE_MOTOR
        if action == "terminate":
            self.disarm("Flight termination: motors off")
            return
        mode = {"hold": HOLD, "land": LAND, "return": RTL}[action]
        if self.cm[MODE] != mode:
            enter(self.cm, mode)

    def datalink_restored(self) -> None:
        self.messages.append((5, "Ground station back"))

    def plant_restored(self) -> None:
        self.messages.append((5, "Plant link restored"))

    def set_mode(self, mode: Mode) -> tuple[bool, str]:
        if mode == self.mode:
            return True, ""
        if mode == Mode.OFFBOARD and not self.stream_fresh():
            return False, "Offboard denied: no setpoint stream"
        if mode == Mode.TAKEOFF:
            return self.takeoff()
        if mode == Mode.FOLLOW and not self.flying():
            return False, "Follow me denied: not flying (take off first)"
        if mode == Mode.ORBIT:  # PX4's orbit without a DO_ORBIT: 1 m around where the vehicle is
            nan = math.nan
            return self.orbit(nan, nan, nan, nan, nan, nan, nan)
        if mode == Mode.RTL and not self.armed:
            return False, "Return denied: not armed"
        if mode in MANUAL_MODES and not self.sticks_fresh():
            return False, f"Mode {mode.name.lower()} denied: no manual control input (MANUAL_CONTROL)"
        enter(self.cm, int(mode))
        self.messages.append((6, f"Mode {mode.name.lower()}"))
        return True, ""

    # ---- once per tick -------------------------------------------------------------------------

    def announce(self, event: int) -> None:
        """The messages of an update()'s event."""
        if event == EVENT_SETPOINT_LOST:
            self.messages.append(
                (2, f"Failsafe: offboard setpoints lost for {self.settings.setpoint_timeout:g} s, landing")
            )
        elif event == EVENT_LANDED:
            self.messages.append((6, "Landed, disarmed"))
        elif event == EVENT_PREFLIGHT_DISARM:
            self.messages.append((6, f"Disarmed by auto preflight disarming: not taken off within COM_DISARM_PRFLT "
                                     f"{self.settings.disarm_preflight:g} s"))  # fmt: skip
        elif event == EVENT_TAKEOFF_DONE:
            self.messages.append((6, "Takeoff complete, holding"))
        elif event == EVENT_HOME_REACHED:
            to = int(self.cm[RTL_TO])
            self.messages.append((6, f"Rally point {to} reached, landing" if to else "Home reached, landing"))
        elif event in (EVENT_GEOFENCE, EVENT_GEOFENCE_GOING_ON):
            action = GEOFENCE_ACTIONS[self.settings.geofence_action]
            what = geofence.BREACHES.get(int(self.cm[GF_BREACH]), "breached")
            if event == EVENT_GEOFENCE_GOING_ON:
                action = f"{action}, not taken: {self.mode.name.lower()} goes on"
            self.messages.append((2, f"Geofence breached: {what}; action: {action}"))
        elif event == EVENT_BATTERY:
            self.messages.append(self.battery_message())
        elif event == EVENT_STICKS_LOST:
            action = self.cm[STICK_ACTION]
            said = ("none, a landing or return goes on" if action == RC_LOSS_GOES_ON
                    else RC_LOSS_ACTIONS[int(action)])  # fmt: skip
            if not math.isnan(self.cm[STICK_DEADLINE]):
                said += f" in {self.settings.fail_act_t:g} s (COM_FAIL_ACT_T), holding until then"
            self.messages.append((2, f"Manual control lost: no MANUAL_CONTROL for {self.settings.rc_loss_timeout:g} "
                                     f"s; action: {said}"))  # fmt: skip
        elif event == EVENT_TARGET_LOST:
            if self.cm[TGT_TIME] < -1e8:
                self.messages.append((4, "Follow me: no target yet (FOLLOW_TARGET); holding"))
            else:
                self.messages.append((4, f"Follow target lost: no FOLLOW_TARGET for {FOLLOW_TIMEOUT:g} s; holding"))
        elif event == EVENT_TARGET_BACK:
            self.messages.append((6, "Follow target back; following"))
        elif event == EVENT_ORBITS_DONE:
            self.messages.append((6, f"Orbit done: {self.cm[ORBIT_TURNS]:g} turns; holding"))
        elif event == EVENT_STICKS_ACTION:
            action = "return" if self.mode == Mode.RTL else "land"
            self.messages.append((2, f"Failsafe: manual control still lost; {action}"))
        elif event == EVENT_STICKS_REGAINED:
            self.messages.append((5, f"Manual control regained; mode {self.mode.name.lower()}"))
        elif event == EVENT_CONTROLLER_FAILED:
            self.messages.append((2, "Failsafe: the controller commanded a non-finite value; flying the "
                                     "backstepping, landing"))  # fmt: skip

    def battery_message(self) -> tuple[int, str]:
        """The STATUSTEXT of the battery's new level (EVENT_BATTERY): how much is left and what the vehicle does."""
        cm = self.cm
        level = int(cm[BAT_WARNING])
        text = f"Battery {BATTERY_WARNINGS[level]}: {cm[BAT_REMAINING]:.0%} remaining"
        if level == 1:
            return 4, text
        wanted = {HOLD: "warning", RTL: "return", LAND: "land"}[battery_action(cm, level)]
        mode = self.mode.name.lower().replace("rtl", "return")
        if wanted != "warning" and mode != wanted:
            wanted = f"{wanted}, not taken: {mode} goes on"
        return (2 if level == 2 else 1), f"{text}; action: {wanted}"

    def update(self, tick: int, now: float, state: VehicleState) -> Reference | None:
        """Advance to tick ``tick`` at simulated time ``now`` [s] with the measured state. Returns the
        altitude and attitude reference (:attr:`reference`), or None when disarmed."""
        s = state
        event = update(self.cm, tick, float(now), float(s.x), float(s.y), float(s.altitude), float(s.vx),
                       float(s.vy), float(s.climb_rate), float(s.yaw))  # fmt: skip
        self.announce(event)
        return self.reference if self.armed else None
