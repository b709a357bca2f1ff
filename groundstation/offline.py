"""``quadsitl sim``: the paper's experiment (or any preset) in one process, no network.

Builds the vehicle of a preset (:class:`groundstation.vehicle.Vehicle`: the plant of ``sitl`` and the autopilot's
tick of ``autopilot``, composed once) and flies it as ``quadsitl fly`` does: on the ground first, then armed in
offboard on the setpoints of the reference, every tick through the same compiled functions as the processes. It
writes telemetry CSV(s), ``metrics.json`` and the figures. A run whose state diverges (:func:`sitl.plant.inside`)
ends there: its CSV and metrics hold the ticks flown before it, and ``metrics.json`` says when (``diverged``,
``diverged_at``), as ``quadsitl fly`` does.

A preset flown on sensors (its ``sensors``: ``--state sensors``) is flown on the autopilot's estimate of the
plant's sensor datagram of each tick, after SENSOR_GROUND_S on the ground. telemetry.csv then has the estimate in
x..r and the truth in x_true..r_true.
"""

from __future__ import annotations

import functools
import json
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from autopilot import mission_protocol as mp
from autopilot.control_params import MEM_PLUG_FAILED_TICK
from autopilot.factory import make_controller
from autopilot.flight_log import log_of
from autopilot.missions import Missions
from autopilot.setpoints import Frame
from groundstation import mission_files, trajectories
from groundstation.figures import write_figures, write_mission_figure, write_path_figure
from groundstation.metrics import battery_use, channel_outputs, estimate_rms, position_metrics, run_metrics
from groundstation.mission_files import MISSION_DURATION, Mission
from groundstation.progress import announce_if_slow
from groundstation.setpoint_grid import grid_setpoints
from groundstation.telemetry_csv import (
    BATTERY_COLUMNS,
    SENSOR_COLUMNS,
    TRUTH_COLUMNS,
    columns_from_arrays,
    stacked,
    write_csv,
)
from groundstation.vehicle import (
    R_BATTERY,
    R_FORCES,
    R_INPUTS,
    R_REF,
    R_SEEN,
    R_SENSORS,
    R_STATE,
    R_XY_REF,
    ROW_SIZE,
    SENSING_ROW_SIZE,
    Setpoints,
    Vehicle,
    ground_ticks,
)
from quadsitl import ulog
from quadsitl.cli_util import UsageError
from quadsitl.compile_cache import compiling
from quadsitl.compiled_frames import euler_rates_to_body_rates
from quadsitl.config import Preset
from quadsitl.frames import PX4_HOME
from quadsitl.state import Reference
from sitl.plant import outside_what


@dataclass
class MissionFlight:
    """How a mission flown by ``quadsitl sim`` went: the items reached ({"seq", "t"}: t [s] from arming, the tick
    after which the executor said so), whether it ended landed and disarmed within its duration, and where it
    was when it did not."""

    reached: list[dict]
    landed: bool
    where: str = ""


@dataclass
class SimResult:
    """Arrays with one row per control tick. Units: SI, radians; NED for positions and velocities."""

    t: np.ndarray  # (N,) [s]
    state: np.ndarray  # (N, 12) VehicleState fields (Euler-angle rates): the truth x(k) at the start of tick k
    reference: np.ndarray  # (N, 4) altitude, roll, pitch, yaw flown (autopilot.stream_frames.reference_shown)
    inputs: np.ndarray  # (N, 4) u1..u4 commanded
    forces: np.ndarray  # (N, 4) commanded motor forces [N]
    diverged_at: float | None = None  # [s]: the time of the tick whose state left the bounds (None: it did not)
    diverged_what: str = ""  # what left its bound (sitl.plant.outside_what)
    estimate: np.ndarray | None = None  # (N, 12) what the controller flew on (sensor mode); ``state`` is the truth
    position_reference: np.ndarray | None = None  # (N, 2) x, y flown [m, NED]; NaN while not controlled
    mission: MissionFlight | None = None  # a mission's flight: how it went
    controller_failed_at: float | None = None  # [s]: when a plugged controller commanded a non-finite value
    battery: np.ndarray | None = None  # (N, 5) the battery the autopilot knew: V, A, mAh, J, share left
    sensors: np.ndarray | None = None  # (N, 17) sensor mode: the estimator's report (telemetry_csv.SENSOR_COLUMNS)

    def body_rates(self, state: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) body rates p, q, r [rad/s] from the Euler-angle rates of ``state`` (default: the truth), eq (1)."""
        s = self.state if state is None else state
        return np.array([euler_rates_to_body_rates(r[6], r[7], r[9], r[10], r[11]) for r in s]).reshape(-1, 3)


def fly_offline(vehicle: Vehicle, setpoints: Setpoints, duration: float,
                progress: Callable[[float], None] | None = None) -> SimResult:  # fmt: skip
    """Fly ``vehicle`` as ``quadsitl fly`` flies it: on the ground first with the motors off (on sensors, while the
    estimator aligns: :func:`groundstation.vehicle.ground_ticks`), then armed in offboard on ``setpoints`` for
    ``duration`` seconds, or until the state diverges. ``progress`` is called with the simulated seconds flown."""
    period = vehicle.period
    vehicle.fly(ground_ticks(vehicle.preset), record=False)
    vehicle.start_offboard(setpoints)
    n = round(duration / period)
    rows, flown = vehicle.fly(n, progress=None if progress is None else (lambda k: progress(k * period)))
    return result_of(vehicle, rows, flown < n)


def result_of(vehicle: Vehicle, rows: np.ndarray, diverged: bool) -> SimResult:
    """The rows of a flight (R_*) as a :class:`SimResult`; ``diverged``: the flight ended on a state out of bounds
    (``vehicle.state``)."""
    flown = len(rows)
    failed = vehicle.mem[MEM_PLUG_FAILED_TICK]  # the tick + 1 (0: none), counted from the vehicle's first
    first = vehicle.tick - flown  # the rows' first tick: their t = 0
    battery = rows[:, R_BATTERY : R_BATTERY + 5]
    return SimResult(np.arange(flown) * vehicle.period, rows[:, R_STATE : R_STATE + 12], rows[:, R_REF : R_REF + 4],
                     rows[:, R_INPUTS : R_INPUTS + 4], rows[:, R_FORCES : R_FORCES + 4],
                     flown * vehicle.period if diverged else None, outside_what(vehicle.plant.x) if diverged else "",
                     rows[:, R_SEEN : R_SEEN + 12] if vehicle.sensing else None,
                     rows[:, R_XY_REF : R_XY_REF + 2],
                     controller_failed_at=(failed - 1 - first) * vehicle.period if failed else None,
                     battery=battery if vehicle.preset.battery is not None else None,
                     sensors=rows[:, R_SENSORS:SENSING_ROW_SIZE] if vehicle.sensing else None)  # fmt: skip


def rows_of(res: SimResult) -> np.ndarray:
    """The flight's rows as :func:`groundstation.vehicle.record` lays them out (R_*; :func:`result_of`'s inverse,
    without the sensors' report): the sweeps' kept trajectories."""
    seen = res.state if res.estimate is None else res.estimate
    battery = np.full((len(res.t), 5), np.nan) if res.battery is None else res.battery
    rows = np.column_stack([res.state, seen, res.reference, res.position_reference, res.inputs, res.forces, battery])
    assert rows.shape[1] == ROW_SIZE
    return rows


def fly_mission(vehicle: Vehicle, mission: Mission, duration: float,
                progress: Callable[[float], None] | None = None) -> SimResult:  # fmt: skip
    """Fly ``mission`` as ``quadsitl fly --mission`` flies it: stored as an upload stores it (each item through the
    autopilot's parser: :attr:`groundstation.mission_files.Mission.flown`, a landing after a mission that does not
    land; its geofence and rally points as their uploads store them), on the ground first (on sensors, while the
    estimator aligns), AUTO.MISSION selected, armed (which starts
    it); the mission executor (:mod:`autopilot.missions`) after every tick, as the autopilot process runs it. The
    rows are the armed ticks, up to the disarm, or ``duration`` seconds, or a state out of bounds."""
    c, period = vehicle.commander, vehicle.period
    missions = Missions(vehicle.home)
    try:
        missions.protocol.store(tuple(mp.parse_item(it.message_fields()) for it in mission.flown))
    except mp.ItemRefusedError as exc:
        raise UsageError(f"--mission {mission.path}: the vehicle refuses it: {exc}") from None
    for kind, items in ((mp.MISSION_TYPE_FENCE, mission.fence), (mp.MISSION_TYPE_RALLY, mission.rally)):
        reason = missions.protocol.store_other(kind, items) if items else ""  # as fly uploads them, after the mission
        if reason:
            raise UsageError(f"--mission {mission.path}: the vehicle refuses it: {reason}")
    missions.sync(c)
    vehicle.fly(ground_ticks(vehicle.preset), record=False)
    vehicle.seen()
    first = vehicle.tick
    ok, why, _ = missions.start(c, c.now)  # selected on the ground, then armed, as fly's ground station does
    if ok:
        ok, why = c.arm()
    if not ok:
        raise UsageError(f"--mission {mission.path}: {why}")
    missions.armed(c, c.now)
    reached: list[dict] = []

    def after_tick() -> bool:
        for out in missions.step(c, c.now):
            if out.kind == "MISSION_ITEM_REACHED":
                reached.append({"seq": out.fields["seq"], "t": round((vehicle.tick - 1 - first) * period, 6)})
        return c.armed

    n = round(duration / period)
    rows, flown = vehicle.fly(n, progress=None if progress is None else (lambda k: progress(k * period)),
                              after_tick=after_tick)  # fmt: skip
    landed = not c.armed
    if landed:  # the tick that disarmed is not an armed tick: fly's telemetry ends before it
        rows = rows[:-1]
    diverged = not landed and flown < n
    where = ""
    if not landed and not diverged:
        ex = missions.executor
        where = (f"the mission did not end within --duration {duration:g} simulated s (current item {ex.current} of "
                 f"{len(mission.items)}, mission_state {ex.mission_state}, "
                 f"{len({r['seq'] for r in reached})} items reached)")  # fmt: skip
    res = result_of(vehicle, rows, diverged)
    res.mission = MissionFlight(reached, landed, where)
    return res


@dataclass
class OfflineRun:
    """What ``quadsitl sim`` produced."""

    results: dict[str, SimResult]
    metrics: dict[str, dict]
    files: list[Path] = field(default_factory=list)


def grid_of(trajectory: str, path: Callable, reference: Reference, period: float, first: int,
            ticks: int, frame: Frame) -> Setpoints:  # fmt: skip
    """The setpoints of ``path`` (made from ``trajectory`` and ``reference``) on ``quadsitl fly``'s grid of ``ticks``
    ticks of ``period`` [s] from tick ``first``, parsed in ``frame``. A named trajectory's are made once for the
    same arguments (a sweep's trials share them; they are only read); a CSV file's each time (it may change)."""
    if Path(trajectory).is_file():
        return _grid(path, period, first, ticks, frame)
    return _named_grid(trajectory, reference, period, first, ticks, frame)


def _grid(path: Callable, period: float, first: int, ticks: int, frame: Frame) -> Setpoints:
    return Setpoints.of(((first + g, sp) for g, sp in grid_setpoints(path, period, ticks)), frame)


@functools.lru_cache(maxsize=8)
def _named_grid(trajectory: str, reference: Reference, period: float, first: int, ticks: int,
                frame: Frame) -> Setpoints:  # fmt: skip
    return _grid(trajectories.make(trajectory, reference), period, first, ticks, frame)


def run_offline(
    preset: Preset,
    controllers: Sequence[str],
    duration: float | None = None,
    integrator: str | None = None,
    substeps: int | None = None,
    rates: Sequence[float] | None = None,
    poles: Sequence[float] | None = None,
    progress: Callable[[float], None] | None = None,
    trajectory: str = "step",
    mission: Mission | None = None,
    home: tuple[float, float, float] = PX4_HOME,
    controller_values: dict[str, float] | None = None,
    metrics: bool = True,
    announce: bool = False,
) -> tuple[dict[str, SimResult], dict[str, dict]]:
    """Fly each controller on a fresh vehicle, on the setpoints of ``trajectory`` (:func:`groundstation.trajectories.
    make`; ``step``: the preset's reference, the paper's experiment) made on ``quadsitl fly``'s grid
    (:mod:`groundstation.setpoint_grid`), for ``duration`` seconds (default: a position trajectory's own, else the
    preset's); or ``mission`` instead (:func:`fly_mission`: ``duration`` bounds it, default MISSION_DURATION), its
    waypoints placed from ``home`` (lat, lon [deg], alt [m AMSL]). All controllers are built (and their gains
    checked: with a position trajectory or a mission, the position loop's too) and every setpoint checked by the
    autopilot's parser before any flight starts, so bad input fails fast.

    ``controller_values``: the first controller's parameters, when it plugs in (:mod:`autopilot.plugin`). Without
    ``metrics`` the runs' metrics are not computed (a sweep takes its own from the telemetry): {} instead. With
    ``announce``, building the controllers and the first vehicle's loop, when it takes more than a second (they
    compile), is said on stderr.

    ``progress``, when given, is called now and then with the simulated seconds done so far over all
    the runs: it reaches ``len(controllers) × duration`` at the end."""
    path = trajectories.make(trajectory, preset.reference)
    position = isinstance(path, trajectories.PositionTrajectory)

    def vehicle_of(controller) -> Vehicle:
        return Vehicle(preset, controller.kind, controller.v, controller.c, integrator, substeps, home, controller.plug)

    with announce_if_slow(compiling("sim", preset.sensors is not None), enabled=announce):
        built = {kind: make_controller(preset, kind, rates=rates, poles=poles, position_loop=position or bool(mission),
                                       values=controller_values if i == 0 else None)
                 for i, kind in enumerate(controllers)}  # fmt: skip
        first_vehicle = vehicle_of(next(iter(built.values())))
        first_vehicle.compile()
    duration = (
        duration
        or (MISSION_DURATION if mission else None)
        or (path.duration if position else None)
        or preset.sim.duration
    )
    period, first = preset.sim.period, ground_ticks(preset)
    ticks = round(duration / period)
    results, found = {}, {}
    for i, (kind, controller) in enumerate(built.items()):
        vehicle = first_vehicle if i == 0 else vehicle_of(controller)
        done = None if progress is None else (lambda s, before=i * duration: progress(before + s))
        if mission is not None:
            res = fly_mission(vehicle, mission, duration, done)
        else:
            if i == 0:
                setpoints = grid_of(trajectory, path, preset.reference, period, first, ticks, vehicle.frame())
            res = fly_offline(vehicle, setpoints, duration, done)
        results[kind] = res
        flown = len(res.t) > 0  # a run that diverged at its first tick flew nothing: no metrics (None)
        if metrics:
            found[kind] = run_metrics(res.t, channel_outputs(res.state), res.reference, res.inputs) if flown else None
    return results, found


def telemetry_columns(res: SimResult, rates: bool = True) -> dict[str, np.ndarray]:
    """The run's telemetry.csv as {column: values} (telemetry_csv.COLUMNS; in sensor mode the estimate flown in
    x..r, the truth and the sensors after: telemetry_csv.SENSING_COLUMNS), as ``quadsitl fly``'s. Without ``rates``
    the body rates p, q, r are NaN (a sweep's metrics do not read them, and they cost one call per row:
    docs/performance.md#a-flights-files)."""

    def body(state: np.ndarray) -> np.ndarray:
        return res.body_rates(state) if rates else np.full((len(state), 3), np.nan)

    seen = res.state if res.estimate is None else res.estimate
    columns = columns_from_arrays(res.t, seen, body(seen), res.reference, res.inputs, res.forces,
                                  res.position_reference)  # fmt: skip
    if res.estimate is not None:
        columns.update(zip(TRUTH_COLUMNS, [*res.state[:, :9].T, *body(res.state).T], strict=True))
        columns.update(zip(SENSOR_COLUMNS, res.sensors.T, strict=True))
    if res.battery is not None:
        columns.update(zip(BATTERY_COLUMNS, res.battery.T, strict=True))
    return columns


def telemetry_rows(res: SimResult, rates: bool = True) -> np.ndarray:
    """The run's rows of telemetry.csv (:func:`telemetry_columns`, in their order)."""
    return stacked(telemetry_columns(res, rates))


def tracking(results: dict[str, SimResult]) -> dict[str, dict]:
    """Each run's position tracking (:func:`groundstation.metrics.position_metrics`): the truth against the
    horizontal reference flown, as ``quadsitl fly``'s metrics.json has it for a position trajectory."""
    return {k: position_metrics(r.state[:, 0], r.state[:, 1], r.position_reference[:, 0], r.position_reference[:, 1],
                                -r.state[:, 2], r.reference[:, 0]) for k, r in results.items()}  # fmt: skip


def write_outputs(
    out: Path,
    preset: Preset,
    results: dict[str, SimResult],
    metrics: dict[str, dict],
    settings: dict,
    figures: bool = True,
    mission: Mission | None = None,
    home: tuple[float, float, float] = PX4_HOME,
) -> list[Path]:
    """telemetry.csv and flight.ulg (first controller), telemetry_<other>.csv, metrics.json and fig2–fig4 PNGs.

    metrics.json's ``diverged`` and ``diverged_at`` [s] (null when it did not) are those of the run in
    telemetry.csv, as in ``quadsitl fly``'s; with more than one controller, ``diverged_at_by_controller`` has
    each run's."""
    out.mkdir(parents=True, exist_ok=True)
    files = []
    for i, (kind, res) in enumerate(results.items()):
        path = out / ("telemetry.csv" if i == 0 else f"telemetry_{kind}.csv")
        columns = telemetry_columns(res)
        write_csv(path, stacked(columns))
        files.append(path)
        if i == 0:  # the flight's ULog, as fly's (PX4's topics: autopilot.flight_log)
            ulog.write(out / "flight.ulg", log_of(columns, preset, kind, home, mission is not None))
            files.append(out / "flight.ulg")
    mpath = out / "metrics.json"
    first = next(iter(results.values()))
    diverged = {"diverged": first.diverged_at is not None, "diverged_at": first.diverged_at}
    if len(results) > 1:
        diverged["diverged_at_by_controller"] = {k: r.diverged_at for k, r in results.items()}
    report = {"preset": preset.name, **settings, **diverged, "runs": metrics}
    tracked = {k: r for k, r in results.items() if r.position_reference is not None and
               np.isfinite(r.position_reference).all(axis=1).any()}  # fmt: skip
    if tracked:
        report["position"] = tracking(tracked)
    if first.battery is not None:  # as fly's: what the flight drew from its battery
        report["battery"] = battery_use(dict(zip(BATTERY_COLUMNS, first.battery.T)))
    if first.estimate is not None:  # as fly's: the sensors flown and the estimate's RMS error
        names = ("x", "y", "altitude", "roll", "pitch", "yaw")

        def columns(s: np.ndarray) -> dict[str, np.ndarray]:
            return dict(zip(names, (s[:, 0], s[:, 1], -s[:, 2], s[:, 6], s[:, 7], s[:, 8])))

        report.update(state="sensors", sensors=asdict(preset.sensors),
                      estimate_rms=estimate_rms(columns(first.estimate), columns(first.state)))  # fmt: skip
    mpath.write_text(json.dumps(report, indent=2) + "\n")
    files.append(mpath)
    flight = first.mission
    doc = None
    if mission is not None and flight is not None:  # as fly's: the items, when each was reached, the disarm
        doc = mission_files.report(mission, home, flight.reached, len(first.t) * preset.sim.period if flight.landed
                                   else None)  # fmt: skip
        (out / "mission.json").write_text(json.dumps(doc, indent=2) + "\n")
        files.append(out / "mission.json")
    runs = {
        k: {"t": r.t, "outputs": channel_outputs(r.state), "reference": r.reference, "inputs": r.inputs}
        for k, r in results.items()
        if len(r.t)
    }
    if figures and runs:
        files += write_figures(runs, out, f"preset {preset.name}")
        if doc is not None and len(first.t):
            data = {"x": first.state[:, 0], "y": first.state[:, 1]}
            files.append(write_mission_figure(out, data, doc, f"preset {preset.name}, sim, {mission.path}"))
        for kind, r in list(tracked.items())[: 1 if doc is None else 0]:
            files.append(write_path_figure(out, r.state[:, 0], r.state[:, 1], r.position_reference[:, 0],
                                           r.position_reference[:, 1], f"preset {preset.name}, sim, {kind}, "
                                           f"{settings.get('trajectory', 'step')}"))  # fmt: skip
    return files
