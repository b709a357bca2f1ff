"""Divergence: a state that is not finite or out of its bounds ends a run, with one check (sitl.plant.inside) at one
moment (the start of a tick, before the controller sees the state) in every runtime: the sweeps' batch engine,
``quadsitl sim``, the plant process under ``quadsitl fly`` and ``quadsitl up``; and the autopilot never flies a
non-finite state."""

import dataclasses
import json
import math
import socket
import subprocess
import textwrap
import time

import numpy as np
import pytest
from pymavlink import mavutil

from groundstation import vehicle
from groundstation.offline import run_offline
from groundstation.sweep import engine
from groundstation.sweep.run import fly as fly_batch
from groundstation.sweep.spec import parse_spec
from groundstation.sweep.trials import trial_preset
from groundstation.telemetry_csv import read_csv
from quadsitl import codec, wire
from quadsitl.config import load_preset, preset_toml
from sitl import plant, tick
from sitl import vehicle as plant_vehicle
from tests.test_fly import alive, children_of, quadsitl

pytestmark = [pytest.mark.timeout(300), pytest.mark.usefixtures("batch_engine")]  # the engine compiled first

DIVERGING = """
    description = "roll's PD made unstable in one trial of two (ω·T above 2)"
    preset = "paper"
    controller = "pd"
    duration = 0.5
    [vary]
    gains.kp2 = { dist = "grid", values = [100.0, 4.5e6] }
"""


def unstable_preset(tmp_path, **initial):
    """The paper's vehicle under a PD whose roll loop is unstable at T = 1 ms (kp2 = 4.5e6: ω·T above 2): valid
    gains, a state past π/2 of roll within tens of milliseconds. ``initial`` replaces initial-state fields."""
    p = load_preset("paper")
    pd = dataclasses.replace(p.controller, type="pd", pd_kp=(100.0, 4.5e6, 100.0, 100.0))
    p = dataclasses.replace(p, controller=pd, initial=dataclasses.replace(p.initial, **initial))
    path = tmp_path / "unstable.toml"
    path.write_text(preset_toml(p))
    return path


def test_one_check_for_every_runtime():
    assert engine.inside is plant.inside and tick.inside is plant.inside  # the batch engine, the plant's lockstep
    assert vehicle.inside is plant.inside  # sim
    assert plant_vehicle.state_inside is plant.state_inside  # the plant's x(0), real time
    assert engine.DEFAULT_LIMITS is plant.DEFAULT_LIMITS is vehicle.DEFAULT_LIMITS
    base = np.zeros(12)
    cases = {  # index, value → inside the default bounds
        (0, 1e5): True, (0, 1.0000001e5): False, (5, -1e4): True, (5, 1.0001e4): False,
        (6, math.pi / 2 - 1e-9): True, (6, math.pi / 2): False, (7, -math.pi / 2): False,  # tilt: strictly below
        (8, 1000 * 2 * math.pi): True, (8, 1001 * 2 * math.pi): False, (11, 1e3): True, (9, -1000.5): False,
        (3, math.nan): False, (1, math.inf): False, (10, -math.inf): False,
    }  # fmt: skip
    for (i, value), want in cases.items():
        x = base.copy()
        x[i] = value
        assert plant.inside(tuple(x), plant.DEFAULT_LIMITS) is want, (i, value)
        assert plant.state_inside(x) is want, (i, value)
        assert engine.inside(tuple(x), np.array(engine.DEFAULT_LIMITS)) is want, (i, value)
    x = base.copy()
    x[6] = math.pi / 2
    assert plant.outside_what(x) == "|roll| = 1.5708 rad is not < 1.5708 (tilt bound)"
    x[6], x[5] = 0.0, math.nan
    assert plant.outside_what(x) == "|vz| = nan m/s is not <= 10000 (speed bound)"


def test_sim_diverges_at_the_tick_the_batch_engine_does(cli, tmp_path):
    """The same configuration, the same tick: the batch engine's trial and `quadsitl sim` on its preset."""
    spec = parse_spec(textwrap.dedent(DIVERGING), "diverging")
    m = fly_batch(spec, np.array([0, 1])).metrics
    assert m[0, engine.M_DIVERGED] == 0.0 and m[1, engine.M_DIVERGED] == 1.0
    at = m[1, engine.M_DIVERGED_AT]
    assert 0.0 < at < 0.1
    preset = trial_preset(spec, 1)
    results, _ = run_offline(preset, ["pd"], spec.duration)
    res = results["pd"]
    assert res.diverged_at == at and len(res.t) == m[1, engine.M_TICKS] == round(at / spec.period)
    assert "|roll| = " in res.diverged_what and "(tilt bound)" in res.diverged_what
    assert np.all(np.isfinite(res.state)) and np.abs(res.state[:, 6]).max() < math.pi / 2
    # the command line: exit status 3, one line, the ticks flown in telemetry.csv, metrics.json says when
    path = tmp_path / "trial.toml"
    path.write_text(preset_toml(preset))
    r = cli("sim", "--preset", str(path), "--duration", "0.5", "--out", str(tmp_path / "sim"), "--no-figures", "-q")
    assert r.returncode == 3, r.stderr
    assert r.stderr.count("quadsitl sim: the state diverged at t = ") == 1 and f"t = {at:.3f} s (pd)" in r.stderr
    report = json.loads((tmp_path / "sim" / "metrics.json").read_text())
    assert report["diverged"] is True and report["diverged_at"] == at and "diverged_at_by_controller" not in report
    assert len(read_csv(tmp_path / "sim" / "telemetry.csv")["t"]) == round(at / spec.period)


def test_sim_compares_and_reports_each_run_and_an_initial_state_out_of_bounds(cli, tmp_path):
    r = cli("sim", "--preset", str(unstable_preset(tmp_path)), "--compare", "--duration", "0.3", "--out",
            str(tmp_path / "both"), "--no-figures", "-q")  # fmt: skip
    assert r.returncode == 3, r.stderr
    report = json.loads((tmp_path / "both" / "metrics.json").read_text())
    by = report["diverged_at_by_controller"]
    assert report["diverged"] is True and report["diverged_at"] == by["pd"] and 0 < by["pd"] < 0.1
    assert by["backstepping"] is None and report["runs"]["backstepping"]["altitude"]["peak_abs_u"] > 0
    assert len(read_csv(tmp_path / "both" / "telemetry_backstepping.csv")["t"]) == 300
    # A roll rate past 10³ rad/s from the start: diverged at t = 0, nothing flown, no metrics.
    r = cli("sim", "--preset", str(unstable_preset(tmp_path, roll_rate=2e3)), "--out", str(tmp_path / "spin"), "-q")
    assert r.returncode == 3, r.stderr
    assert "diverged at t = 0.000 s (pd): |roll rate| = 2000 rad/s is not <= 1000 (rate bound); 0 ticks" in r.stderr
    report = json.loads((tmp_path / "spin" / "metrics.json").read_text())
    assert report["diverged_at"] == 0.0 and report["runs"] == {"pd": None}
    assert len(read_csv(tmp_path / "spin" / "telemetry.csv")["t"]) == 0


def test_a_normal_sim_has_not_diverged(cli, tmp_path):
    r = cli("sim", "--duration", "0.2", "--out", str(tmp_path), "--no-figures", "-q")
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "metrics.json").read_text())
    assert report["diverged"] is False and report["diverged_at"] is None


def test_fly_ends_promptly_when_the_plant_diverges_at_the_tick_sim_says(cli, tmp_path):
    preset = unstable_preset(tmp_path)
    s = cli("sim", "--preset", str(preset), "--duration", "1", "--out", str(tmp_path / "sim"), "--no-figures", "-q")
    assert s.returncode == 3, s.stderr
    at = json.loads((tmp_path / "sim" / "metrics.json").read_text())["diverged_at"]
    out = tmp_path / "fly"
    started = time.monotonic()
    r = subprocess.run(quadsitl("fly", "--preset", str(preset), "--duration", "5", "--out", str(out),
                                "--no-figures", "-q"), capture_output=True, text=True, timeout=120)  # fmt: skip
    took = time.monotonic() - started
    assert r.returncode == 3, r.stderr  # docs/failures.md
    assert took < 30, took  # no stall: a diverged plant ends the run (a few seconds, most of it starting up)
    # the plant's line names the quantity, its value and the bound; fly's line says when, on the flight's clock
    plant_line = next(line for line in r.stderr.splitlines() if line.startswith("plant: diverged at t = "))
    assert "|roll| = " in plant_line and "is not < 1.5708 (tilt bound)" in plant_line, plant_line
    assert r.stderr.count("quadsitl fly: the plant's state diverged at t = ") == 1
    assert f"diverged at t = {at:.3f} s of the flight" in r.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    rows = read_csv(out / "telemetry.csv")
    assert metrics["diverged"] is True and metrics["diverged_at"] == at  # the very tick of sim and the batch engine
    assert len(rows["t"]) == round(at / 0.001) and np.allclose(rows["t"], np.arange(len(rows["t"])) * 0.001)
    assert np.abs(rows["roll"]).max() < math.pi / 2
    sim = read_csv(tmp_path / "sim" / "telemetry.csv")
    assert np.abs(rows["roll"] - sim["roll"]).max() < 1e-3  # the same flight, to the wire's float32
    # the ground station heard it from the autopilot, which relayed the plant's STATUSTEXT: it is in flight.tlog
    tlog = mavutil.mavlink_connection(str(out / "flight.tlog"))
    texts = []
    while (msg := tlog.recv_match(type="STATUSTEXT")) is not None:
        texts.append((msg.severity, msg.text))
    said = [sev for sev, text in texts if text.startswith("Simulation diverged at t = ")]
    assert said == [wire.mavlink.MAV_SEVERITY_CRITICAL], texts


def test_up_stops_and_tells_the_ground_station_when_the_plant_diverges(tmp_path):
    """Roll and yaw rates of 10³ rad/s (within the bounds) from the start: the plant's roll passes π/2 within a
    few ticks of the autopilot's first answer."""
    gcs = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    gcs.bind(("127.0.0.1", 0))
    gcs.settimeout(0.2)
    port = gcs.getsockname()[1]
    preset = unstable_preset(tmp_path, roll_rate=1e3, yaw_rate=1e3)
    up = subprocess.Popen(quadsitl("up", "--preset", str(preset), "-q", "--no-zenoh", "--gcs-listen", "127.0.0.1:0",
                                   "--gcs-remote", f"127.0.0.1:{port}", "--api-listen", "127.0.0.1:0", "--api-remote",
                                   "none"), stderr=subprocess.PIPE, text=True)  # fmt: skip
    link = wire.link(255, 190)
    said, kids = [], []
    try:
        end = time.monotonic() + 60
        while time.monotonic() < end and up.poll() is None:
            if len(kids) < 2:
                kids = children_of(up.pid)
            try:
                data = gcs.recv(65535)
            except TimeoutError:
                continue
            said += [m for m in link.parse_buffer(data) or [] if m.get_type() == "STATUSTEXT"]
        _, err = up.communicate(timeout=15)
        assert up.returncode == 3, err  # docs/failures.md
        assert "plant: diverged at t = 0.00" in err and "(tilt bound)" in err
        assert "quadsitl up: the plant's state diverged (above; the ground stations were told" in err
        texts = [m.text for m in said if m.severity == wire.mavlink.MAV_SEVERITY_CRITICAL]
        assert any(t.startswith("Simulation diverged at t = 0.00") for t in texts), texts
        time.sleep(0.2)
        assert len(kids) == 2 and not [p for p in kids if alive(p)]  # nothing left behind
    finally:
        gcs.close()
        if up.poll() is None:
            up.kill()
            up.wait()


def test_the_autopilot_never_flies_a_non_finite_state():
    """What the plant sent before it stopped sending, a NaN or an infinity in the state frame: refused (counted by
    the process as a plant-link error), never flown nor answered; the next finite state flies."""
    from autopilot import tick as kernel
    from autopilot.commander import Commander
    from autopilot.control_params import PD, control_array
    from autopilot.plugin import no_plug
    from autopilot.stream_frames import StreamFrames
    from quadsitl.param_arrays import vehicle_array

    p = load_preset("paper")
    frame, tx = np.zeros(codec.FRAME_MAX, dtype=np.uint8), np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    st, scratch, mem = np.zeros(codec.DECODED_SIZE), np.zeros(codec.DECODED_SIZE), np.zeros(kernel.MEM_SIZE)
    v, c = vehicle_array(p.vehicle), control_array(p.poles(), 0.001, p.controller.pd_kp, p.controller.pd_kd)
    io = np.zeros(kernel.IO_SIZE, dtype=np.int64)
    io[kernel.LAST_USEC] = -1
    cm = Commander()
    records = np.zeros(1, dtype=np.uint8)

    def deliver(k: int, x) -> int:
        n = codec.encode_state(frame, k & 0xFF, 1, 25, codec.usec_of(k, 0.001), tuple(x))
        return kernel.autopilot_tick(frame, n, scratch, st, 0.001, PD, no_plug(), cm.cm, mem, v, c, 0.0, 10.0, tx, io,
                                     records, StreamFrames(2, (47.0, 8.0, 488.0), 40.0, False).out)  # fmt: skip

    assert deliver(0, [0.0] * 12) & kernel.ANSWER
    before = st.copy()
    for bad in (math.nan, math.inf, -math.inf, 1e39):  # 1e39 is inf in the frame's float32 (but a finite angle)
        for i in (0, 5, 9, 11) if bad == 1e39 else (0, 5, 6, 9, 11):
            x = [0.0] * 12
            x[i] = bad
            assert deliver(1, x) == kernel.REFUSED, (bad, i)
            assert np.array_equal(st, before) and io[kernel.LAST_USEC] == 0 and io[kernel.TICK] == 0
    assert deliver(1, [0.0] * 12) & kernel.ANSWER and io[kernel.TICK] == 1
