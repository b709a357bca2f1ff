"""A recorded flight as records, file → :class:`Recording`: pure, no I/O but reading the file (:func:`load`).

A :class:`Recording` holds one record per stream and tick, packed in the schema of :mod:`quadsitl.telemetry`
(v4) for ``quadsitl/<vehicle>/{state,setpoint,actuators,status}``; :mod:`groundstation.replay` (``quadsitl
replay``) paces and publishes it. The file is a ``telemetry.csv`` (from ``quadsitl sim`` or ``quadsitl
fly``; :func:`records_from_csv`) or a ``.tlog`` (MAVLink telemetry log: an 8-byte big-endian µs timestamp
before each raw MAVLink 1/2 frame, as ``quadsitl gcs``, MAVProxy and QGroundControl write it;
:func:`records_from_tlog`). A file that cannot be replayed raises :class:`ReplayError`.

**From a telemetry.csv.** T is the median step of the ``t`` column [s] (``--period`` when there is one
row); tick = round(t/T). state ← x, y, z, vx, vy, vz [m, m/s, NED], roll, pitch, yaw [rad], p, q, r
[rad/s, FRD]; setpoint ← altitude_ref [m], roll_ref, pitch_ref, yaw_ref [rad], x_ref, y_ref [m, NED];
actuators ← u1..u4, f1..f4; status ← armed 1, mode 1 (offboard), failsafe 0, offboard_tick 0 (the CSV holds
the offboard flight, with t = 0 at its first tick), and the battery's columns when it has them (NaN when not).
Values go out exactly as written in the CSV. A CSV
written before schema v3 has no x_ref, y_ref columns: they go out as NaN (not controlled), with a note.

**From a .tlog.** The vehicle is the system whose component 1 (the autopilot) sends the first ATTITUDE;
other systems' telemetry is ignored. Each ATTITUDE with a new tick (tick = round(time_boot_ms·10⁻³/T),
T = ``--period``, t = time_boot_ms·10⁻³ [s]) makes one record per stream, holding the latest value of each
field received before the next ATTITUDE (NaN for a field never seen). An ATTITUDE whose tick is not after
the previous record's (a vehicle restart, an out-of-order log) is skipped and counted. The tlog's own
wall-clock timestamps are not used: time is the vehicle's. Bytes that are not a timestamped, CRC-valid
frame are skipped (the scanner resynchronises) and counted:

- state: roll, pitch, yaw, p, q, r from ATTITUDE; x..vz from LOCAL_POSITION_NED. ``quadsitl fly``/``gcs``
  turn LOCAL_POSITION_NED off on their link (``gcs.UNNEEDED_STREAMS``), so x..vz are NaN in their logs.
- setpoint: the vehicle's own targets while they are fresh (within 1 s of vehicle time): ATTITUDE_TARGET's
  quaternion → roll/pitch/yaw_ref (:func:`quadsitl.frames.quaternion_to_euler`), POSITION_TARGET_LOCAL_NED
  (frame LOCAL_NED) z → altitude_ref = −z, and x, y → x_ref, y_ref when its type_mask makes the position a
  target (bits 1 and 2, "ignore x/y", clear), else NaN (the horizontal position is not controlled).
  Otherwise the ground station's own commands to the vehicle, SET_ATTITUDE_TARGET and
  SET_POSITION_TARGET_LOCAL_NED, read the same way: what was *commanded*, which the vehicle flies only in
  offboard.
- actuators: u1..u4 are not in any MAVLink message (ATTITUDE_TARGET's thrust is u1 clamped to [0, 1] of
  the total, the torques are nowhere; the motor forces are u after saturation, so u cannot be inverted
  from them): NaN. f1..f4 invert :mod:`autopilot.gcs_messages`: ACTUATOR_OUTPUT_STATUS actuator[j] =
  F_j/F_max, or, when the log has none, SERVO_OUTPUT_RAW PWM 1000..2000 µs (0 when disarmed: F = 0) with
  a 1 µs = F_max/1000 resolution, times F_max from ``--preset`` (and its reversible motors map
  1000..2000 µs to −F_max..F_max). That is this autopilot's encoding; PX4's outputs are not forces.
- status: the battery from the vehicle's BATTERY_STATUS (the cells' voltages summed, current, charge and energy
  drawn, share left; NaN where it says unknown, or before one); armed and mode from the vehicle's HEARTBEAT
  (``base_mode`` & SAFETY_ARMED,
  :meth:`quadsitl.wire.Mode.from_px4` on ``custom_mode``), updated between heartbeats (they come at
  1 Hz of *wall* time, a few per lockstep flight) by the vehicle's accepted COMMAND_ACK to a logged
  COMMAND_LONG/INT: ARM_DISARM, DO_SET_MODE, NAV_LAND. Mode 255 when not known (no heartbeat yet, or a
  PX4 mode that :meth:`~quadsitl.wire.Mode.from_px4` does not map to one of this autopilot's modes); armed 0
  until known. failsafe 1 while the heartbeat says CRITICAL or EMERGENCY. offboard_tick: the first tick of
  the current armed offboard stretch, −1 outside one; as exact as the mode changes are placed, i.e. to
  within an ATTITUDE interval.
"""

from __future__ import annotations

import csv
import itertools
import math
import statistics
from array import array
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import NamedTuple

from groundstation.telemetry_csv import COLUMNS
from quadsitl import telemetry, wire
from quadsitl.config import ConfigError, load_preset
from quadsitl.frames import quaternion_to_euler

mavlink = wire.mavlink
NAN = math.nan
DEFAULT_PERIOD = 0.001  # [s]
MODE_UNKNOWN = 255
TARGET_STALE = 1.0  # [s] of vehicle time: an older ATTITUDE_TARGET / POSITION_TARGET_LOCAL_NED is not used
STATE, SETPOINT = telemetry.FIELDS["state"][2:], telemetry.FIELDS["setpoint"][2:]  # the CSV columns they take
# The CSV columns read, by name, in record order: t, then each stream's fields (altitude = −z is redundant).
# A vehicle with a battery has its columns last (the status record's battery fields; NaN for one without).
CSV_FIELDS = ("t", *STATE, *SETPOINT, *telemetry.FIELDS["actuators"][2:], *telemetry.BATTERY_FIELDS)
assert set(CSV_FIELDS) == set(COLUMNS) - {"altitude"} | set(telemetry.BATTERY_FIELDS), "CSV columns, Zenoh fields"
CSV_OPTIONAL = ("x_ref", "y_ref")  # new in schema v3: an older telemetry.csv replays them as NaN
POSITION_IGNORED = 1 | 2  # SET_/POSITION_TARGET_LOCAL_NED type_mask bits: ignore x, ignore y


class ReplayError(Exception):
    """A file that cannot be replayed: one line naming the file and what is wrong, exit status 2."""


@dataclass
class Recording:
    """One record per stream and tick, in increasing tick order, packed in the wire format of
    :data:`quadsitl.telemetry.STREAMS` (``payload[stream]`` is the records concatenated)."""

    source: str  # the file, for messages
    period: float  # T [s]
    ticks: array = field(default_factory=lambda: array("Q"))  # control ticks, strictly increasing
    times: array = field(default_factory=lambda: array("d"))  # simulated time t [s] of each record
    payload: dict[str, bytearray] = field(default_factory=lambda: {s: bytearray() for s in telemetry.STREAMS})
    notes: list[str] = field(default_factory=list)  # what the user should know about this file's mapping

    def __len__(self) -> int:
        return len(self.ticks)

    def append(
        self,
        tick: int,
        t: float,
        state: Sequence[float],
        setpoint: Sequence[float],
        actuators: Sequence[float],
        status: tuple[float, ...],
    ) -> None:
        """Add one tick: state = x..r (12 values), setpoint = altitude_ref..y_ref (6), actuators =
        u1..u4, f1..f4 (8), status = (armed, mode, failsafe, offboard_tick, then the battery's V, A, mAh, J, share
        left)."""
        s, p = telemetry.STREAMS, self.payload
        p["state"] += s["state"].pack(tick, t, *state)
        p["setpoint"] += s["setpoint"].pack(tick, t, *setpoint)
        p["actuators"] += s["actuators"].pack(tick, t, *actuators)
        p["status"] += s["status"].pack(tick, t, *status)
        self.ticks.append(tick)
        self.times.append(t)

    def records(self, stream: str) -> list[tuple]:
        """The records of one stream, decoded (tuples in :data:`quadsitl.telemetry.FIELDS` order)."""
        return list(telemetry.STREAMS[stream].iter_unpack(self.payload[stream]))

    @property
    def duration(self) -> float:
        """Simulated seconds one pass covers: first to last record, plus one period [s]."""
        return self.times[-1] - self.times[0] + self.period if self.ticks else 0.0


def load(path: Path, period: float = DEFAULT_PERIOD, preset: str = "paper") -> Recording:
    """A telemetry CSV or a tlog (by extension) → its recording. Raises ReplayError."""
    if not path.exists():
        raise ReplayError(f"{path}: no such file; expected a telemetry.csv (from quadsitl sim or fly) or a .tlog")
    if path.is_dir():
        raise ReplayError(f"{path}: is a directory; expected a telemetry.csv or a .tlog file")
    suffix = path.suffix.lower()
    if suffix == ".csv":
        return records_from_csv(path, period)
    if suffix == ".tlog":
        try:
            actuators = load_preset(preset).actuators
        except ConfigError as exc:
            raise ReplayError(f"--preset: {exc}") from None
        return records_from_tlog(path, period, actuators.max_thrust, actuators.reversible, preset)
    raise ReplayError(
        f"{path}: unknown file type {path.suffix or '(no extension)'!r}; expected .csv (a telemetry.csv from "
        "quadsitl sim or fly) or .tlog (a MAVLink telemetry log)"
    )


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise ReplayError(f"{path}: cannot read: {exc.strerror}") from None


def records_from_csv(path: Path, period: float = DEFAULT_PERIOD) -> Recording:
    """A telemetry CSV (:mod:`groundstation.telemetry_csv` columns, any order, extra columns ignored) →
    its recording. T = the median step of ``t``; ``period`` [s] only when there is a single row.
    Raises ReplayError naming the file, the line and the column."""
    try:
        text = _read_bytes(path).decode("utf-8")
    except UnicodeDecodeError:
        raise ReplayError(f"{path}: not a text file; expected a telemetry CSV with a header line") from None
    reader = csv.reader(text.splitlines())
    try:
        header = next(reader, None)
        if header is None:
            raise ReplayError(f"{path}: empty file; expected a header line with the columns {', '.join(COLUMNS)}")
        names = [h.strip() for h in header]
        missing = [c for c in CSV_FIELDS if c not in names and c not in (*CSV_OPTIONAL, *telemetry.BATTERY_FIELDS)]
        if missing:
            raise ReplayError(
                f"{path}: missing column{'s' if len(missing) > 1 else ''} {', '.join(missing)}; a telemetry CSV "
                f"has the columns {', '.join(COLUMNS)}"
            )
        index = [names.index(c) if c in names else None for c in CSV_FIELDS]
        rows: list[tuple[int, list[float]]] = []
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue
            line = reader.line_num
            if len(row) != len(names):
                raise ReplayError(f"{path}: line {line} has {len(row)} fields, the header {len(names)}")
            values = []
            for column, i in zip(CSV_FIELDS, index):
                if i is None:  # an optional column the file does not have
                    values.append(NAN)
                    continue
                try:
                    values.append(float(row[i]))
                except ValueError:
                    raise ReplayError(f"{path}: line {line}, column {column}: {row[i]!r} is not a number") from None
            rows.append((line, values))
    except csv.Error as exc:
        raise ReplayError(f"{path}: line {reader.line_num}: not valid CSV: {exc}") from None
    if not rows:
        raise ReplayError(f"{path}: no data rows after the header")
    times = [values[0] for _line, values in rows]
    for (line, _), t in zip(rows, times):
        if not (math.isfinite(t) and t >= 0.0):
            raise ReplayError(f"{path}: line {line}, column t: {t!r}; expected a finite time ≥ 0 [s]")
    steps = [b - a for a, b in itertools.pairwise(times)]
    T = statistics.median(steps) if steps else period
    if not T > 0.0:
        raise ReplayError(f"{path}: column t does not increase (median step {T!r} s); expected one row per tick")
    rec = Recording(str(path), T)
    absent = [c for c in CSV_OPTIONAL if c not in names]
    if absent:
        rec.notes.append(f"no {', '.join(absent)} column{'s' if len(absent) > 1 else ''} (a telemetry.csv from "
                         "before schema v3): NaN, the horizontal position not controlled")  # fmt: skip
    ns, nsp, na = len(STATE), len(SETPOINT), len(telemetry.FIELDS["actuators"]) - 2
    for line, values in rows:
        t = values[0]
        tick = round(t / T)
        if rec.ticks and tick <= rec.ticks[-1]:
            raise ReplayError(
                f"{path}: line {line}: t = {t!r} s is tick {tick} (T = {T:g} s), not after the previous row's "
                f"tick {rec.ticks[-1]}; expected t increasing by about T per row"
            )
        v = values[1:]
        # armed, offboard, no failsafe, the flight started at tick 0 (t = 0); the battery (NaN: none)
        status = (1, 1, 0, 0, *v[ns + nsp + na :])
        rec.append(tick, t, v[:ns], v[ns : ns + nsp], v[ns + nsp : ns + nsp + na], status)
    return rec


# ---- tlog ----------------------------------------------------------------------------------------------

_TLOG_FORMAT = (
    "expected 8-byte big-endian timestamps, each followed by a MAVLink 1 or 2 frame (a .tlog as quadsitl gcs, "
    "MAVProxy or QGroundControl write it)"
)


class TlogScan(NamedTuple):
    messages: list  # pymavlink messages, in file order
    skipped: int  # bytes that are not a timestamped MAVLink frame (garbage, a truncated last frame)
    unknown: int  # frames of message ids the common dialect does not know (skipped)


def tlog_messages(data: bytes) -> TlogScan:
    """The MAVLink messages of a tlog (8-byte timestamp, then a MAVLink 1 or 2 frame, repeated). A frame is
    taken when its CRC checks; when it does not, the parser resynchronises byte by byte. A frame of an id
    the common dialect does not know (so no CRC to check) is skipped whole only if the next timestamped
    frame starts right after it, else it is taken for garbage too."""
    mav = wire.link(0, 0)
    v1, v2 = mavlink.PROTOCOL_MARKER_V1, mavlink.PROTOCOL_MARKER_V2
    out = []
    pos, skipped, unknown, n = 0, 0, 0, len(data)
    while pos + 8 < n:
        start = pos + 8
        stx = data[start]
        if stx == v2 and start + 3 <= n:
            end = start + 12 + data[start + 1] + (mavlink.MAVLINK_SIGNATURE_BLOCK_LEN if data[start + 2] & 1 else 0)
        elif stx == v1 and start + 2 <= n:
            end = start + 8 + data[start + 1]
        else:
            end = n + 1
        msg = None
        if end <= n:
            try:
                msg = mav.decode(bytearray(data[start:end]))
            except Exception:  # garbage trips pymavlink in many ways (CRC, lengths, struct, text)
                msg = None
        if isinstance(msg, mavlink.MAVLink_unknown) and not (end == n or (end + 8 < n and data[end + 8] in (v1, v2))):
            msg = None
        if msg is None:
            pos, skipped = pos + 1, skipped + 1
            continue
        if isinstance(msg, mavlink.MAVLink_unknown):
            unknown += 1
        else:
            out.append(msg)
        pos = end
    return TlogScan(out, skipped + (n - pos), unknown)


@dataclass
class _Status:
    armed: bool | None = None
    mode: wire.Mode | None = None
    failsafe: bool = False
    offboard_tick: int = -1


class _TlogState:
    """The latest value of every field, fed with the log's messages in file order."""

    def __init__(self, system: int, max_thrust: float | None, reversible: bool, use_servo: bool) -> None:
        self.system = system
        self.max_thrust = max_thrust
        self.reversible = reversible
        self.use_servo = use_servo
        self.position = [NAN] * 6  # x, y, z, vx, vy, vz
        self.vehicle_attitude: tuple[float, float, float, float] | None = None  # roll, pitch, yaw refs, t
        self.vehicle_altitude: tuple[float, float] | None = None  # altitude_ref, t
        self.vehicle_xy: tuple[float, float, float] | None = None  # x_ref, y_ref (NaN: not a target), t
        self.gcs_attitude: tuple[float, float, float] | None = None
        self.gcs_altitude: float | None = None
        self.gcs_xy: tuple[float, float] | None = None
        self.forces = [NAN] * 4
        self.battery = [NAN] * 5  # V, A, mAh, J, share left: BATTERY_STATUS's (NaN: not known)
        self.status = _Status()
        self.commands: dict[int, tuple[float, float, float]] = {}  # command → params 1..3 last sent
        self.heard: set[str] = set()  # message types from the vehicle
        self.target_sources: dict[str, set[str]] = {"attitude": set(), "altitude": set(), "position": set()}

    def from_vehicle(self, m) -> bool:
        return m.get_srcSystem() == self.system and m.get_srcComponent() == wire.AUTOPILOT_COMPONENT_ID

    def feed(self, m) -> None:
        kind = m.get_type()
        if self.from_vehicle(m):
            self.heard.add(kind)
            handler = getattr(self, "_vehicle_" + kind.lower(), None)
        elif getattr(m, "target_system", -1) in (0, self.system):
            handler = getattr(self, "_gcs_" + kind.lower(), None)
        else:
            handler = None
        if handler is not None:
            handler(m)

    # -- the vehicle's messages
    def _vehicle_local_position_ned(self, m) -> None:
        self.position = [m.x, m.y, m.z, m.vx, m.vy, m.vz]

    def _vehicle_attitude_target(self, m) -> None:
        if not m.type_mask & mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE and (q := _unit(m.q)):
            self.vehicle_attitude = (*quaternion_to_euler(*q), m.time_boot_ms / 1000.0)

    def _vehicle_position_target_local_ned(self, m) -> None:
        if m.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
            return
        t = m.time_boot_ms / 1000.0
        if not m.type_mask & 4:  # bit 2: z ignored
            self.vehicle_altitude = (-m.z, t)
        self.vehicle_xy = (*_horizontal_target(m), t)

    def _vehicle_actuator_output_status(self, m) -> None:
        if self.max_thrust is not None:
            self.forces = [m.actuator[j] * self.max_thrust if m.active >> j & 1 else NAN for j in range(4)]

    def _vehicle_servo_output_raw(self, m) -> None:
        if self.use_servo and self.max_thrust is not None:
            pwm = (m.servo1_raw, m.servo2_raw, m.servo3_raw, m.servo4_raw)
            self.forces = [self._force_of_pwm(p) for p in pwm]

    def _force_of_pwm(self, pwm: int) -> float:
        """Inverse of :func:`autopilot.gcs_messages.pwm`; 0 µs (disarmed) → 0 N."""
        if pwm == 0:
            return 0.0
        c = (pwm - 1000.0) / 1000.0
        return (2.0 * c - 1.0 if self.reversible else c) * self.max_thrust  # type: ignore[operator]

    def _vehicle_heartbeat(self, m) -> None:
        if m.type == mavlink.MAV_TYPE_GCS:
            return
        st = self.status
        st.armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        custom = m.base_mode & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        st.mode = wire.Mode.from_px4(m.custom_mode) if custom else None
        st.failsafe = m.system_status in (mavlink.MAV_STATE_CRITICAL, mavlink.MAV_STATE_EMERGENCY)

    def _vehicle_command_ack(self, m) -> None:
        params = self.commands.get(m.command)
        if m.result != mavlink.MAV_RESULT_ACCEPTED or params is None:
            return
        st = self.status
        if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            st.armed = params[0] >= 0.5
        elif m.command == mavlink.MAV_CMD_DO_SET_MODE and int(params[0]) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            st.mode = wire.Mode.from_px4((int(params[1]) & 0xFF) << 16 | (int(params[2]) & 0xFF) << 24)
        elif m.command == mavlink.MAV_CMD_NAV_LAND:
            st.mode = wire.Mode.LAND

    # -- the ground station's messages to the vehicle
    def _gcs_command_long(self, m) -> None:
        self.commands[m.command] = (m.param1, m.param2, m.param3)

    _gcs_command_int = _gcs_command_long

    def _gcs_set_attitude_target(self, m) -> None:
        if not m.type_mask & mavlink.ATTITUDE_TARGET_TYPEMASK_ATTITUDE_IGNORE and (q := _unit(m.q)):
            self.gcs_attitude = quaternion_to_euler(*q)

    def _gcs_set_position_target_local_ned(self, m) -> None:
        if m.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
            return
        if not m.type_mask & 4:
            self.gcs_altitude = -m.z
        self.gcs_xy = _horizontal_target(m)

    # -- one tick's record
    def setpoint(self, t: float) -> tuple[float, float, float, float, float, float]:
        """altitude_ref, roll_ref, pitch_ref, yaw_ref, x_ref, y_ref at vehicle time t [s]: the vehicle's
        fresh targets, else the ground station's commands, else the vehicle's stale ones, else NaN."""
        va, vz = self.vehicle_attitude, self.vehicle_altitude
        if va is not None and t - va[3] <= TARGET_STALE:
            attitude, a_src = va[:3], "ATTITUDE_TARGET"
        elif self.gcs_attitude is not None:
            attitude, a_src = self.gcs_attitude, "SET_ATTITUDE_TARGET"
        elif va is not None:
            attitude, a_src = va[:3], "ATTITUDE_TARGET"
        else:
            attitude, a_src = (NAN, NAN, NAN), ""
        if vz is not None and t - vz[1] <= TARGET_STALE:
            altitude, z_src = vz[0], "POSITION_TARGET_LOCAL_NED"
        elif self.gcs_altitude is not None:
            altitude, z_src = self.gcs_altitude, "SET_POSITION_TARGET_LOCAL_NED"
        elif vz is not None:
            altitude, z_src = vz[0], "POSITION_TARGET_LOCAL_NED"
        else:
            altitude, z_src = NAN, ""
        vxy = self.vehicle_xy
        if vxy is not None and t - vxy[2] <= TARGET_STALE:
            xy, xy_src = vxy[:2], "POSITION_TARGET_LOCAL_NED"
        elif self.gcs_xy is not None:
            xy, xy_src = self.gcs_xy, "SET_POSITION_TARGET_LOCAL_NED"
        elif vxy is not None:
            xy, xy_src = vxy[:2], "POSITION_TARGET_LOCAL_NED"
        else:
            xy, xy_src = (NAN, NAN), ""
        self.target_sources["attitude"].add(a_src)
        self.target_sources["altitude"].add(z_src)
        self.target_sources["position"].add(xy_src if math.isfinite(xy[0]) else "")
        return (altitude, *attitude, *xy)  # type: ignore[return-value]

    def _vehicle_battery_status(self, m) -> None:
        cells = list(itertools.takewhile(lambda mv: mv != 65535, m.voltages))
        known = m.battery_remaining >= 0
        self.battery = [sum(cells) / 1000.0 if cells else NAN, m.current_battery / 100.0 if m.current_battery >= 0
                        else NAN, float(m.current_consumed) if m.current_consumed >= 0 else NAN,
                        m.energy_consumed * 100.0 if m.energy_consumed >= 0 else NAN,
                        m.battery_remaining / 100.0 if known else NAN]  # fmt: skip

    def status_record(self, tick: int) -> tuple[float, ...]:
        st = self.status
        in_offboard = bool(st.armed) and st.mode == wire.Mode.OFFBOARD
        if not in_offboard:
            st.offboard_tick = -1
        elif st.offboard_tick < 0:
            st.offboard_tick = tick
        mode = MODE_UNKNOWN if st.mode is None else int(st.mode)
        return int(bool(st.armed)), mode, int(st.failsafe), st.offboard_tick, *self.battery


def _horizontal_target(m) -> tuple[float, float]:
    """x_ref, y_ref [m, NED] of a (SET_)POSITION_TARGET_LOCAL_NED: its x, y when the type_mask makes the
    position a target, else NaN, NaN (the horizontal position is not controlled)."""
    if m.type_mask & POSITION_IGNORED:
        return NAN, NAN
    return float(m.x), float(m.y)


def _unit(q: Sequence[float]) -> tuple[float, float, float, float] | None:
    """A quaternion normalised, or None when it has no direction (zero, NaN, inf)."""
    norm = math.sqrt(sum(x * x for x in q))
    if not (math.isfinite(norm) and norm > 1e-6):
        return None
    return tuple(x / norm for x in q)  # type: ignore[return-value]


def records_from_tlog(
    path: Path,
    period: float = DEFAULT_PERIOD,
    max_thrust: float | None = None,
    reversible: bool = False,
    preset: str = "",
) -> Recording:
    """A MAVLink telemetry log → its recording (mapping in the module docstring). ``period``: T [s] of
    the vehicle's control loop; ``max_thrust``: F_max per motor [N] for f1..f4 (None: NaN);
    ``reversible``: the motors' PWM covers −F_max..F_max. Raises ReplayError."""
    data = _read_bytes(path)
    if not data:
        raise ReplayError(f"{path}: empty file; {_TLOG_FORMAT}")
    messages, skipped, unknown = tlog_messages(data)
    if not messages:
        raise ReplayError(f"{path}: no MAVLink messages in {len(data)} bytes; {_TLOG_FORMAT}")
    attitude_id = mavlink.MAVLINK_MSG_ID_ATTITUDE
    system = next(
        (m.get_srcSystem() for m in messages
         if m.get_msgId() == attitude_id and m.get_srcComponent() == wire.AUTOPILOT_COMPONENT_ID),
        None,
    )  # fmt: skip
    if system is None:
        raise ReplayError(
            f"{path}: {len(messages)} MAVLink message{'s' if len(messages) != 1 else ''} but no ATTITUDE from an "
            "autopilot (component 1): nothing to replay"
        )
    kinds = {m.get_type() for m in messages  # what the vehicle's autopilot itself sent, as _TlogState hears it
             if m.get_srcSystem() == system and m.get_srcComponent() == wire.AUTOPILOT_COMPONENT_ID}  # fmt: skip
    state = _TlogState(system, max_thrust, reversible, use_servo="ACTUATOR_OUTPUT_STATUS" not in kinds)
    rec = Recording(str(path), period)
    pending: tuple[int, float, tuple[float, ...]] | None = None  # tick, t, ATTITUDE fields
    backwards = 0
    no_u = (NAN, NAN, NAN, NAN)

    def emit() -> None:
        tick, t, att = pending  # type: ignore[misc]
        rec.append(tick, t, (*state.position, *att), state.setpoint(t), (*no_u, *state.forces),
                   state.status_record(tick))  # fmt: skip

    for m in messages:
        if m.get_msgId() == attitude_id and state.from_vehicle(m):
            t = m.time_boot_ms / 1000.0
            tick = round(t / period)
            att = (m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed)
            if pending is not None and tick == pending[0]:
                pending = (tick, t, att)  # the same tick again (a second link): the newer values
                continue
            if pending is not None:
                emit()
                pending = None
            if rec.ticks and tick <= rec.ticks[-1]:
                backwards += 1
                continue
            pending = (tick, t, att)
        else:
            state.feed(m)
    if pending is not None:
        emit()
    rec.notes.extend(_tlog_notes(state, skipped, unknown, backwards, max_thrust, preset))
    return rec


def _tlog_notes(
    state: _TlogState, skipped: int, unknown: int, backwards: int, max_thrust: float | None, preset: str
) -> list[str]:
    heard, notes = state.heard, []
    if skipped:
        notes.append(f"skipped {skipped} bytes that are not timestamped MAVLink frames")
    if unknown:
        notes.append(f"skipped {unknown} frames of message ids the common dialect does not know")
    if backwards:
        notes.append(f"skipped {backwards} ATTITUDE messages whose tick is not after the previous one "
                     "(a vehicle restart or an out-of-order log)")  # fmt: skip
    if "LOCAL_POSITION_NED" not in heard:
        notes.append("no LOCAL_POSITION_NED from the vehicle: x, y, z, vx, vy, vz are NaN")
    for what, fields in (("attitude", "roll_ref, pitch_ref, yaw_ref"), ("altitude", "altitude_ref"),
                         ("position", "x_ref, y_ref")):  # fmt: skip
        sources = state.target_sources[what]
        known = sorted(s for s in sources if s)
        named = " and ".join(known) or "nothing: NaN"
        notes.append(f"{fields} from {named}" + (" (NaN until the first)" if "" in sources and known else ""))
    if max_thrust is None or not heard & {"ACTUATOR_OUTPUT_STATUS", "SERVO_OUTPUT_RAW"}:
        notes.append("no ACTUATOR_OUTPUT_STATUS or SERVO_OUTPUT_RAW from the vehicle: f1..f4 are NaN")
    else:
        source = "SERVO_OUTPUT_RAW" if state.use_servo else "ACTUATOR_OUTPUT_STATUS"
        notes.append(f"f1..f4 from {source} with F_max = {max_thrust:g} N (--preset {preset})")
    notes.append("u1..u4 are not in MAVLink telemetry: NaN")
    if "HEARTBEAT" not in heard:
        notes.append("no HEARTBEAT from the vehicle: armed and mode only from acknowledged commands")
    return notes
