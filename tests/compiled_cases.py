"""The cases the compiled equations are checked on against the same source run as ordinary Python
(``NUMBA_DISABLE_JIT=1``): the paper experiment end to end, and every equation group on random states.

:func:`compute` runs them all and returns named arrays; ``python -m tests.compiled_cases OUT.npz`` saves
them (the test runs that with the compiler off, and compares with the compiled run in its own process).
"""

from __future__ import annotations

import math
import sys

import numpy as np

from autopilot import commander
from autopilot.backstepping import backstepping
from autopilot.control_params import BACKSTEPPING, MEM_SIZE, PD, control_array
from autopilot.pd import pd
from autopilot.plugin import no_plug
from autopilot.stream_frames import StreamFrames
from autopilot.tick import autopilot_tick
from groundstation.offline import run_offline
from quadsitl import codec, compiled_frames, mixer
from quadsitl.config import SensorParams, WindParams, load_preset
from quadsitl.param_arrays import actuator_array, vehicle_array
from sitl import actuators, battery, dynamics, integrators, tick
from sitl.plant import OUT_CURRENT, OUT_SIZE
from sitl.sensors import Sensors
from sitl.wind import air_arrays

RANDOM_STATES = 200


def _random_states(rng: np.random.Generator, n: int) -> np.ndarray:
    """States within the paper's ranges: positions ±10 m, velocities ±5 m/s, roll and pitch ±80°, any yaw,
    Euler-angle rates ±3 rad/s."""
    s = np.empty((n, 12))
    s[:, 0:3] = rng.uniform(-10, 10, (n, 3))
    s[:, 3:6] = rng.uniform(-5, 5, (n, 3))
    s[:, 6:8] = rng.uniform(-1.39, 1.39, (n, 2))
    s[:, 8] = rng.uniform(-math.pi, math.pi, n)
    s[:, 9:12] = rng.uniform(-3, 3, (n, 3))
    return s


def compute() -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name in ("paper", "x500"):
        preset = load_preset(name)
        results, _ = run_offline(preset, ["backstepping", "pd"], duration=1.0 if name == "paper" else 0.5)
        for kind, r in results.items():
            out[f"{name}/{kind}/state"], out[f"{name}/{kind}/forces"] = r.state, r.forces

    rng = np.random.default_rng(20201)
    states = _random_states(rng, RANDOM_STATES)
    inputs = rng.uniform(-50, 50, (RANDOM_STATES, 4))
    refs = np.column_stack([rng.uniform(0, 10, RANDOM_STATES), rng.uniform(-1.5, 1.5, (RANDOM_STATES, 3))])
    preset = load_preset("x500")
    v = vehicle_array(preset.vehicle)
    lagged = actuator_array(preset.actuators)
    lagged[2:4] = 0.02, 0.04
    c = control_array(preset.poles(), preset.sim.period, preset.controller.pd_kp, preset.controller.pd_kd,
                      preset.controller.max_tilt, -100.0, 100.0)  # fmt: skip
    rows: dict[str, list] = {}
    for i in range(RANDOM_STATES):
        s, u, ref = tuple(states[i]), tuple(inputs[i]), tuple(refs[i])
        f = mixer.inputs_to_forces(u, v[15])
        row = {
            "derivatives": dynamics.derivatives(s, u, inputs[i, 0] * 3.0, v, dynamics.CALM),
            "derivatives in wind": dynamics.derivatives(s, u, 1.5, v, (*inputs[i, :3], *inputs[-1 - i, :3])),
            "euler": integrators.euler(s, u, 1.5, v, dynamics.CALM, 0.001),
            "rk4": integrators.rk4(s, u, 1.5, v, (*inputs[-1 - i, :3], 0.0, 1.0, -2.0), 0.001),
            "forces_to_inputs": mixer.forces_to_inputs(f, v[15]),
            "inputs_to_forces": f,
            "rotor_speeds": mixer.rotor_speeds(f, v[12]),
            "allocate": mixer.allocate(u, v[15], 0.0, 10.0),
            "advance": actuators.advance(f, tuple(inputs[-1 - i]), 0.001, lagged),
            "backstepping": backstepping(s, ref, u, v, c)[0] + backstepping(s, ref, u, v, c)[1],
            "pd": pd(s, ref, v, c),
            "body_rates": compiled_frames.euler_rates_to_body_rates(s[6], s[7], s[9], s[10], s[11]),
            "euler_rates": compiled_frames.body_rates_to_euler_rates(s[6], s[7], s[9], s[10], s[11]),
            "quaternion": compiled_frames.euler_to_quaternion(s[6], s[7], s[8]),
            "wrap": (compiled_frames.wrap_pi(s[8] * 7.0),),
        }
        for key, value in row.items():
            rows.setdefault(key, []).append(np.ravel(np.array(value, dtype=np.float64)))
    out.update({f"random/{key}": np.array(values) for key, values in rows.items()})
    out.update(_ticks(states, refs))
    return out


def _ticks(states: np.ndarray, refs: np.ndarray) -> dict[str, np.ndarray]:
    """The processes' fused ticks: frames in and out, byte for byte, over a short closed loop."""
    preset = load_preset("paper")
    v, a = vehicle_array(preset.vehicle), actuator_array(preset.actuators)
    c = control_array(preset.poles(), preset.sim.period, preset.controller.pd_kp, preset.controller.pd_kd)
    rx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    st, scratch, mem = np.zeros(codec.DECODED_SIZE), np.zeros(codec.DECODED_SIZE), np.zeros(MEM_SIZE)
    io_ap = np.zeros(11, dtype=np.int64)
    io_ap[0], io_ap[4], io_ap[8], io_ap[9] = -1, 4, 1, 1
    records = np.zeros(4 * 512, dtype=np.uint8)
    io_pl = np.zeros(tick.IO_SIZE, dtype=np.int64)
    io_pl[tick.LAST_USEC] = -1
    x, motors, out, received, commanded = states[0].copy(), np.zeros(4), np.zeros(OUT_SIZE), np.zeros(4), np.zeros(4)
    battery.start(out[OUT_CURRENT:], a)  # the paper's ideal supply: nothing to report
    gusty = WindParams(speed_m_s=3.0, from_deg=200.0, turbulence="severe", gust_m_s=2.0, gust_start_s=0.05, seed=4,
                       force_n=(0.5, -0.2, 0.1))  # fmt: skip
    air = air_arrays(gusty)  # in a wind, with an external force
    cm = commander.Commander()
    cm.on_altitude_setpoint(float(refs[0, 0]))
    cm.on_attitude_setpoint(*map(float, refs[0, 1:]))
    cm.arm()
    cm.set_mode(commander.Mode.OFFBOARD)
    frames_out, bytes_out = [], []
    sens = Sensors(SensorParams(), preset.sim.period, preset.vehicle.gravity).arrays  # truth mode: not touched
    tick.encode_tick(tx, io_pl, x, out, air[0], sens, 0, preset.sim.period)
    no_frames = StreamFrames(2, (47.0, 8.0, 488.0), 40.0, False).out  # no stream on any link
    for k in range(300):
        n = int(io_pl[tick.TX_LEN])
        rx[:n] = tx[:n]
        kind = BACKSTEPPING if k < 150 else PD
        io_ap[3] = k % 4  # the batch's row
        autopilot_tick(rx, n, scratch, st, preset.sim.period, kind, no_plug(), cm.cm, mem, v, c, -1e4, 1e4, tx,
                       io_ap, records, no_frames)  # fmt: skip
        m = int(io_ap[1])
        bytes_out.append(tx[:m].copy())
        rx[:m] = tx[:m]
        tick.lockstep_tick(rx, m, codec.usec_of(k, preset.sim.period), 1e4, received, commanded, x, motors, out, v, a,
                           *air, preset.sim.period, 1, 0, tx, io_pl, sens, k)  # fmt: skip
        frames_out.append(np.concatenate([x, mem, cm.cm]))
        bytes_out.append(records.copy())
    return {"ticks/values": np.array(frames_out), "ticks/answers": np.concatenate(bytes_out).astype(np.float64)}


if __name__ == "__main__":
    np.savez(sys.argv[1], **compute())
