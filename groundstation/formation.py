"""A fleet's formation manoeuvre and how well it was flown, pure: for ``quadsitl fly --vehicles N --formation KIND``.

The plan (:func:`plan`), in one frame common to the fleet: north and east [m] from the first vehicle's home (each
vehicle's home is its place on the starting grid, :attr:`groundstation.fleet.VehiclePlan.offset`), altitude up,
time t [s] from the tick at which every vehicle armed (the fleet's plant holds its clock there, so every vehicle's
flight time is the same clock). Phases, each a minimum-jerk move (zero velocity and acceleration at both ends):

1. **take off**: each vehicle climbs from the ground to the formation's altitude where it stands;
2. **form up**: each flies straight to its slot in the formation (``line``: abreast, ``grid``: ⌈√N⌉ columns,
   ``circle``: evenly round a circle), centred on the centroid of the starting grid, facing north. Slots are
   given to vehicles by the assignment that minimises the sum of squared distances flown (:func:`assign`): with
   every vehicle on the same timing law, straight paths of such an assignment do not cross (Turpin, Michael and
   Kumar, "CAPT: Concurrent assignment and planning of trajectories for multiple robots", IJRR 2014);
3. **translate**: the formation flies ``distance`` metres north;
4. **rotate**: it turns 90° clockwise about its centre, each vehicle turning its heading with it;
5. **hold**; then the ground station lands every vehicle where it is (``MAV_CMD_NAV_LAND``).

Each vehicle flies its part as an offboard position trajectory in its own local frame (:func:`vehicle_table`: the
CSV ``t, x, y, altitude, yaw`` that :func:`groundstation.trajectories.position_from_csv` reads).

How well it was flown (:func:`fleet_metrics`), from each vehicle's telemetry (the truth, in sensor mode):

- **formation error** of vehicle i at t: ‖(p_i − p̄) − (s_i − s̄)‖, its place relative to the fleet's centroid
  against its slot's relative to the slots' centroid [m, 3-D]: the shape, wherever the whole formation is;
- **tracking error**: ‖p_i − s_i‖, against the plan itself;
- **minimum separation**: the smallest distance between two vehicles [m, 3-D], when and which.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from groundstation.trajectories import MAX_CLIMB, MAX_HORIZONTAL_SPEED
from quadsitl.cli_util import UsageError

KINDS = ("line", "grid", "circle")
PHASES = ("take off", "form up", "translate", "rotate", "hold")
CRUISE = 2.0  # [m/s] the peak horizontal speed the plan asks of a vehicle (PX4's MPC_XY_CRUISE is 5)
MIN_PHASE = 4.0  # [s] the shortest phase
PEAK = 1.875  # the minimum-jerk profile's peak rate, in units of (distance / duration)


def min_jerk(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The minimum-jerk profile s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ on τ ∈ [0, 1] (clamped outside: 0 and 1, at rest) and
    ds/dτ, for each τ of an array."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10.0 + tau * (-15.0 + 6.0 * tau)), 30.0 * tau**2 * (1.0 - tau) ** 2


def slots(kind: str, n: int, spacing: float) -> np.ndarray:
    """(n, 2) slot offsets (forward, right) [m] about the formation's centre (their centroid), facing its heading;
    neighbours ``spacing`` apart."""
    if kind not in KINDS:
        raise UsageError(f"--formation {kind!r}: expected one of {', '.join(KINDS)}")
    if kind == "line":  # abreast: along the right axis
        return np.array([(0.0, (i - (n - 1) / 2.0) * spacing) for i in range(n)]).reshape(n, 2)
    if kind == "grid":
        cols = math.ceil(math.sqrt(n))
        grid = np.array([(-(i // cols) * spacing, (i % cols) * spacing) for i in range(n)]).reshape(n, 2)
        return grid - grid.mean(axis=0)  # centred on its centroid, a last row short or not
    if n == 1:
        return np.zeros((1, 2))
    radius = spacing / (2.0 * math.sin(math.pi / n))  # a chord of `spacing` between neighbours
    return np.array([(radius * math.cos(2.0 * math.pi * i / n), radius * math.sin(2.0 * math.pi * i / n))
                     for i in range(n)])  # fmt: skip


def assign(cost: np.ndarray) -> np.ndarray:
    """The assignment of rows to columns of the square ``cost`` matrix with the least total cost: ``col[row]``
    (the Hungarian method with potentials, O(n³))."""
    n = cost.shape[0]
    inf = math.inf
    u, v = np.zeros(n + 1), np.zeros(n + 1)
    match = np.zeros(n + 1, dtype=int)  # match[column] = row, 1-based; 0: free
    way = np.zeros(n + 1, dtype=int)
    for row in range(1, n + 1):
        match[0] = row
        col0 = 0
        low = np.full(n + 1, inf)
        used = np.zeros(n + 1, dtype=bool)
        while True:
            used[col0] = True
            r0, delta, col1 = match[col0], inf, 0
            for col in range(1, n + 1):
                if not used[col]:
                    cur = cost[r0 - 1, col - 1] - u[r0] - v[col]
                    if cur < low[col]:
                        low[col], way[col] = cur, col0
                    if low[col] < delta:
                        delta, col1 = low[col], col
            for col in range(n + 1):
                if used[col]:
                    u[match[col]] += delta
                    v[col] -= delta
                else:
                    low[col] -= delta
            col0 = col1
            if match[col0] == 0:
                break
        while col0:
            col1 = way[col0]
            match[col0] = match[col1]
            col0 = col1
    out = np.zeros(n, dtype=int)
    for col in range(1, n + 1):
        out[match[col] - 1] = col - 1
    return out


@dataclass(frozen=True)
class Plan:
    """A formation manoeuvre (see the module's docstring). ``start``: (n, 2) north, east [m] of each vehicle's home
    in the common frame; ``slot``: (n, 2) its slot (forward, right) about the centre; ``times``: each phase's start
    [s] and the end."""

    kind: str
    spacing: float
    altitude: float
    distance: float
    start: np.ndarray
    slot: np.ndarray
    centre: tuple[float, float]
    times: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.start)

    @property
    def duration(self) -> float:
        return self.times[-1]

    def phase(self, t: float) -> str:
        """The phase flown at t [s] ("landing" after the plan)."""
        for name, end in zip(PHASES, self.times[1:], strict=True):
            if t < end:
                return name
        return "landing"

    def heading(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The formation's heading ψ [rad, from north, clockwise] and its rate [rad/s] at each t [s]."""
        t0, t1 = self.times[3], self.times[4]
        s, ds = min_jerk((t - t0) / (t1 - t0))
        return 0.5 * math.pi * s, 0.5 * math.pi * ds / (t1 - t0)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, float, float]:
        """Every vehicle's planned place at t [s]: (n, 3) north, east, altitude [m] in the common frame, (n, 3)
        their rates [m/s], the heading [rad] and its rate (:meth:`along` at one time)."""
        pos, vel, psi, psi_dot = self.along(np.array([t], dtype=float))
        return pos[:, 0], vel[:, 0], float(psi[0]), float(psi_dot[0])

    def along(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Every vehicle's planned place at each of the m times ``t`` [s]: (n, m, 3) north, east, altitude [m] in
        the common frame, (n, m, 3) their rates [m/s], and (m,) the heading [rad] and its rate."""
        _zero, t_climb, t_form, t_move, _t_turn, _end = self.times
        t = np.asarray(t, dtype=float)
        alt_s, alt_ds = min_jerk((t - 0.0) / t_climb)
        form_s, form_ds = min_jerk((t - t_climb) / (t_form - t_climb))
        move_s, move_ds = min_jerk((t - t_form) / (t_move - t_form))
        psi, psi_dot = self.heading(t)
        c, s = np.cos(psi), np.sin(psi)  # (m,), and below a vehicle's (n, 1) against them
        centre = np.stack([self.centre[0] + self.distance * move_s, np.full_like(t, self.centre[1])], axis=-1)
        centre_rate = np.stack([self.distance * move_ds / (t_move - t_form), np.zeros_like(t)], axis=-1)
        fwd, right = self.slot[:, :1], self.slot[:, 1:]
        rotated = np.stack([c * fwd - s * right, s * fwd + c * right], axis=-1)  # (n, m, 2)
        rotated_rate = psi_dot[:, None] * np.stack([-rotated[..., 1], rotated[..., 0]], axis=-1)
        goal = centre + rotated
        goal_rate = centre_rate + rotated_rate
        start = self.start[:, None, :]
        place = start + form_s[:, None] * (goal - start)  # before and while forming up, `goal` stands still
        rate = (form_ds / (t_form - t_climb))[:, None] * (goal - start) + form_s[:, None] * goal_rate
        up = np.broadcast_to(self.altitude * alt_s, place.shape[:2])[..., None]
        climb = np.broadcast_to(self.altitude * alt_ds / t_climb, place.shape[:2])[..., None]
        return np.concatenate([place, up], axis=-1), np.concatenate([rate, climb], axis=-1), psi, psi_dot


def plan(kind: str, starts: Sequence[tuple[float, float]], spacing: float, altitude: float,
         distance: float = 10.0) -> Plan:  # fmt: skip
    """The manoeuvre of ``kind`` for vehicles whose homes are at ``starts`` (north, east [m], common frame), slots
    ``spacing`` metres apart, at ``altitude`` [m], translating ``distance`` [m] north; each phase long enough that
    no vehicle is asked more than CRUISE horizontally or MAX_CLIMB/2 vertically."""
    start = np.asarray(starts, dtype=float).reshape(-1, 2)
    n = len(start)
    offsets = slots(kind, n, spacing)
    centre = start.mean(axis=0)
    cost = ((start[:, None, :] - (centre + offsets)[None, :, :]) ** 2).sum(axis=2)
    slot = offsets[assign(cost)]
    reach = float(np.max(np.hypot(*(centre + slot - start).T))) if n else 0.0
    radius = float(np.max(np.hypot(*slot.T))) if n else 0.0
    climb = max(MIN_PHASE, PEAK * altitude / (MAX_CLIMB / 2.0))
    form = max(MIN_PHASE, PEAK * reach / CRUISE)
    move = max(MIN_PHASE, PEAK * distance / CRUISE)
    turn = max(MIN_PHASE, PEAK * 0.5 * math.pi * radius / CRUISE)
    durations = (climb, form, move, turn, MIN_PHASE)
    times = tuple(float(x) for x in np.concatenate([[0.0], np.cumsum(durations)]))
    return Plan(kind, spacing, altitude, distance, start, slot, (float(centre[0]), float(centre[1])), times)


def vehicle_table(p: Plan, i: int, step: float = 0.05) -> np.ndarray:
    """Vehicle ``i``'s part of the plan in its own local frame (its home at the origin): rows t, x north, y east
    [m], altitude [m], yaw [rad] every ``step`` seconds over the plan, as a position trajectory's CSV has them."""
    t = np.arange(0.0, p.duration + step / 2.0, step)
    pos, _vel, psi, _ = p.along(t)
    table = np.column_stack([t, pos[i, :, 0] - p.start[i, 0], pos[i, :, 1] - p.start[i, 1], pos[i, :, 2], psi])
    climb = float(np.max(np.abs(np.diff(table[:, 3])))) / step
    speed = float(np.max(np.hypot(np.diff(table[:, 1]), np.diff(table[:, 2])))) / step
    if climb > MAX_CLIMB or speed > MAX_HORIZONTAL_SPEED:  # plan() sizes the phases so that this never happens
        raise RuntimeError(f"the formation plan asks {speed:.3g} m/s and {climb:.3g} m/s climb of vehicle {i + 1}")
    return table


def write_vehicle_csv(path, p: Plan, i: int) -> None:
    """:func:`vehicle_table` as the CSV ``t,x,y,altitude,yaw``."""
    table = vehicle_table(p, i)
    lines = ["t,x,y,altitude,yaw"] + [",".join(f"{v:.6f}" for v in row) for row in table]
    path.write_text("\n".join(lines) + "\n")


def common_track(p: Plan, runs: Sequence[Mapping[str, np.ndarray]]) -> tuple[np.ndarray, np.ndarray]:
    """Each vehicle's flown positions on the ticks every vehicle logged: (t [s], (n, len(t), 3) north, east,
    altitude [m] in the common frame). ``runs[i]``: vehicle i's telemetry columns (t, x, y, altitude: its own
    frame; the truth's x_true, y_true, z_true instead when it flew on sensors)."""
    ticks = None
    for run in runs:
        k = np.round(np.asarray(run["t"]) * 1e6).astype(np.int64)
        ticks = k if ticks is None else np.intersect1d(ticks, k)
    track = np.zeros((len(runs), len(ticks), 3))
    for i, run in enumerate(runs):
        k = np.round(np.asarray(run["t"]) * 1e6).astype(np.int64)
        keep = np.isin(k, ticks)
        truth = "x_true" in run
        x = np.asarray(run["x_true" if truth else "x"])[keep]
        y = np.asarray(run["y_true" if truth else "y"])[keep]
        alt = -np.asarray(run["z_true"])[keep] if truth else np.asarray(run["altitude"])[keep]
        track[i] = np.column_stack([x + p.start[i, 0], y + p.start[i, 1], alt])
    return ticks / 1e6, track


def fleet_metrics(p: Plan, t: np.ndarray, track: np.ndarray) -> dict:
    """Formation error, tracking error (per phase: RMS and max over vehicles and time [m]) and the minimum
    separation (see the module's docstring) of the flown ``track`` (:func:`common_track`)."""
    planned = p.along(t)[0]  # (n, len(t), 3)
    shape = (track - track.mean(axis=0)) - (planned - planned.mean(axis=0))
    formation = np.linalg.norm(shape, axis=2)  # (n, len(t))
    tracking = np.linalg.norm(track - planned, axis=2)
    phases = np.array([p.phase(float(tk)) for tk in t])
    per_phase = {}
    for name in (*PHASES, "landing"):
        sel = phases == name
        if not sel.any():
            continue
        per_phase[name] = {
            "from_s": float(t[sel][0]), "to_s": float(t[sel][-1]),
            "formation_rms_m": float(np.sqrt(np.mean(formation[:, sel] ** 2))),
            "formation_max_m": float(formation[:, sel].max()),
            "tracking_rms_m": float(np.sqrt(np.mean(tracking[:, sel] ** 2))),
            "tracking_max_m": float(tracking[:, sel].max()),
        }  # fmt: skip
    n = p.n
    separation = {"min_m": None, "t_s": None, "vehicles": None}
    closest = np.full(len(t), np.nan)  # the smallest separation at each t [m]
    if n > 1:
        i, j = np.triu_indices(n, 1)
        d = np.linalg.norm(track[i] - track[j], axis=2)  # (pairs, len(t))
        closest = d.min(axis=0)
        pair, k = np.unravel_index(int(np.argmin(d)), d.shape)
        separation = {"min_m": float(d[pair, k]), "t_s": float(t[k]), "vehicles": [int(i[pair]) + 1,
                                                                                    int(j[pair]) + 1]}  # fmt: skip
    return {
        "formation": p.kind, "vehicles": n, "spacing_m": p.spacing, "altitude_m": p.altitude,
        "distance_m": p.distance, "phases": dict(zip(PHASES, p.times[:-1], strict=True)), "plan_s": p.duration,
        "per_phase": per_phase, "min_separation": separation,
        "series": {"t": t, "formation_max_m": formation.max(axis=0), "separation_min_m": closest},
    }  # fmt: skip


def format_table(m: dict) -> str:
    """The fleet's metrics as a table: a row per phase, then the minimum separation."""
    lines = [f"formation {m['formation']}, {m['vehicles']} vehicles, {m['spacing_m']:g} m apart at "
             f"{m['altitude_m']:g} m",
             "phase          from [s]  formation rms/max [m]  tracking rms/max [m]"]  # fmt: skip
    for name, ph in m["per_phase"].items():
        lines.append(f"{name:<14} {ph['from_s']:8.2f}  {ph['formation_rms_m']:9.3f} / {ph['formation_max_m']:<9.3f}"
                     f"  {ph['tracking_rms_m']:8.3f} / {ph['tracking_max_m']:.3f}")  # fmt: skip
    sep = m["min_separation"]
    if sep["min_m"] is not None:
        lines.append(f"minimum separation {sep['min_m']:.2f} m, vehicles {sep['vehicles'][0]} and "
                     f"{sep['vehicles'][1]} at t = {sep['t_s']:.2f} s")  # fmt: skip
    return "\n".join(lines)
