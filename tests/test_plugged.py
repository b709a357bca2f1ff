"""Controllers that plug in (quadsitl.controller, autopilot.plugin): the shipped template flies, and every way a
controller can be broken is refused in one line, before or during a flight, never with garbage to the motors."""

from __future__ import annotations

import re
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from autopilot import commander as cmd
from autopilot.plugin import ControllerError, load
from groundstation.offline import run_offline, tracking
from quadsitl.config import load_preset

ROOT = Path(__file__).resolve().parent.parent
TEMPLATE = f"{ROOT / 'examples' / 'controllers' / 'template.py'}:Template"

HEADER = "from quadsitl.controller import Controller, Parameter\nimport math\n"


def controller_file(tmp_path: Path, body: str, name: str = "mine.py") -> Path:
    path = tmp_path / name
    path.write_text(HEADER + textwrap.dedent(body), encoding="utf-8")
    return path


def test_the_template_flies_the_x500_circle_within_1_m_rms():
    x500 = load_preset("x500")
    results, _ = run_offline(x500, [TEMPLATE], trajectory="circle")
    res = results[TEMPLATE]
    track = tracking(results)[TEMPLATE]
    assert res.diverged_at is None and res.controller_failed_at is None
    assert track["horizontal_rms"] < 1.0 and track["altitude_rms"] < 1.0
    assert np.isfinite(res.forces).all()
    # it is the template flying, not the backstepping: a different flight on the same work
    bs, _ = run_offline(x500, ["backstepping"], trajectory="circle")
    assert np.abs(bs["backstepping"].state[:, :3] - res.state[:, :3]).max() > 1e-3


def test_parameters_reach_the_law_and_are_checked():
    plugged = load(TEMPLATE)
    v = np.ones(16)
    assert plugged.values({"kp_xy": 2.0})["kp_xy"] == 2.0
    buf = plugged.plug(v, {"kp_xy": 2.0})[1]
    assert buf[-plugged.memory - len(plugged.parameters)] == 2.0  # the first parameter, where the law reads it
    with pytest.raises(ControllerError, match=r"kp_xy = 99.0: expected a number in \[0, 50\] 1/s²"):
        plugged.values({"kp_xy": 99.0})
    with pytest.raises(ControllerError, match=r"no parameter 'kp' \(it has: kp_xy, kv_xy"):
        plugged.values({"kp": 1.0})
    with pytest.raises(ControllerError, match=r"kv_z·kp_z = 1 must exceed ki_z = 2"):  # the template's own check
        plugged.plug(v, {"kv_z": 1.0, "kp_z": 1.0, "ki_z": 2.0})


BROKEN = {
    "no file": (None, r"no such file"),
    "syntax": ("class C(Controller):\n    law = (\n", r"mine.py:\d+: SyntaxError"),
    "raises on import": ("raise RuntimeError('no gains here')\n",
                         r"importing it raised mine.py:3: RuntimeError: no gains"),
    "no class": ("class Other(Controller):\n    pass\n", r"has no 'C'"),
    "no law": ("class C(Controller):\n    pass\n", r"expected a @staticmethod law\(t, dt, x, sp, model, k, mem, u\)"),
    "wrong arguments": ("class C(Controller):\n    @staticmethod\n    def law(x, u):\n        pass\n",
                        r"law takes \(x, u\): expected \(t, dt, x, sp, model, k, mem, u\)"),
    "bad default": ("class C(Controller):\n    parameters = (Parameter('g1', 5.0, '1/s', 0.0, 1.0, 'a gain'),)\n"
                    "    @staticmethod\n    def law(t, dt, x, sp, model, k, mem, u):\n        pass\n",
                    r"parameter g1: default 5.0: expected a number in \[0, 1\] 1/s"),
    "does not compile": ("class C(Controller):\n    @staticmethod\n    def law(t, dt, x, sp, model, k, mem, u):\n"
                         "        u[0] = {'a': 1}.keys()\n",
                         r"its law does not compile: .*\(mine.py:\d+\)"),
    "NaN at hover": ("class C(Controller):\n    @staticmethod\n    def law(t, dt, x, sp, model, k, mem, u):\n"
                     "        u[0] = math.nan\n        u[1] = u[2] = u[3] = 0.0\n",
                     r"its law commands \[nan, 0.0, 0.0, 0.0\] at hover"),
    "writes nothing": ("class C(Controller):\n    @staticmethod\n    def law(t, dt, x, sp, model, k, mem, u):\n"
                       "        pass\n", r"its law commands \[nan, nan, nan, nan\] at hover"),
}  # fmt: skip


@pytest.mark.parametrize("case", list(BROKEN))
def test_a_broken_controller_is_refused_in_one_line(tmp_path, case):
    body, expected = BROKEN[case]
    path = tmp_path / "mine.py" if body is None else controller_file(tmp_path, body)
    with pytest.raises(ControllerError) as err:
        load(f"{path}:C").plug(np.ones(16))
    message = str(err.value)
    assert "\n" not in message and message.startswith(f"controller {path}:C: ")
    assert re.search(expected, message), message


def test_sim_refuses_a_broken_controller_in_one_line_before_flying(tmp_path):
    path = controller_file(tmp_path, "class C(Controller):\n    @staticmethod\n    def law(t, dt, x, sp, model, k, "
                                     "mem, u):\n        u[0] = undefined_name\n")  # fmt: skip
    out = tmp_path / "run"
    r = subprocess.run([sys.executable, "-m", "groundstation.cli", "sim", "--preset", "x500", "--controller",
                        f"{path}:C", "--trajectory", "circle", "--out", str(out)],
                       capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and "its law does not compile" in lines[0] and "undefined_name" in lines[0], r.stderr
    assert not out.exists()  # nothing written


def test_a_controller_that_fails_in_flight_trips_the_failsafe_and_never_reaches_the_motors(tmp_path):
    """A law that commands NaN from t = 3 s on: from that tick the backstepping flies (the forces stay finite), the
    commander lands (FAILSAFE_CONTROLLER), and the run says when."""
    path = controller_file(
        tmp_path,
        """
        from numba import njit
        from quadsitl.controller import MASS, G, ROLL, PITCH, YAW, P, Q, R, IXX, IYY, IZZ, Z, VZ, SP_ALTITUDE

        class C(Controller):
            @staticmethod
            def law(t, dt, x, sp, model, k, mem, u):
                if t > 3.0:
                    return  # the command stays NaN
                alt = sp[SP_ALTITUDE] if math.isfinite(sp[SP_ALTITUDE]) else -x[Z]
                u[0] = model[MASS] * (model[G] + 4.0 * (alt + x[Z]) + 4.0 * x[VZ])
                u[1] = model[IXX] * (-100.0 * x[ROLL] - 20.0 * x[P])
                u[2] = model[IYY] * (-100.0 * x[PITCH] - 20.0 * x[Q])
                u[3] = model[IZZ] * (-16.0 * x[YAW] - 8.0 * x[R])
        """,
    )
    spec = f"{path}:C"
    from autopilot.control_params import MEM_PLUG_FAILED
    from autopilot.factory import make_controller
    from groundstation.offline import fly_offline
    from groundstation.setpoint_grid import grid_setpoints
    from groundstation.trajectories import make
    from groundstation.vehicle import Setpoints, Vehicle

    x500 = load_preset("x500")
    ctl = make_controller(x500, spec)
    vehicle = Vehicle(x500, ctl.kind, ctl.v, ctl.c, plug=ctl.plug)
    period = x500.sim.period
    setpoints = Setpoints.of(grid_setpoints(make("hold:altitude=5,duration=20", x500.reference), period, 20_000),
                             vehicle.frame())  # fmt: skip
    res = fly_offline(vehicle, setpoints, 20.0)
    assert res.controller_failed_at == pytest.approx(3.0, abs=2 * period)
    assert np.isfinite(res.forces).all() and np.isfinite(res.inputs).all()
    cm = vehicle.commander.cm
    assert cm[cmd.FAILSAFE] == cmd.FAILSAFE_CONTROLLER
    assert vehicle.mem[MEM_PLUG_FAILED] == 0.0 and cm[cmd.ARMED] == 0.0  # landed, disarmed: to fly it again
    altitude = -res.state[:, 2]
    t = res.t
    assert altitude[t < 3.0].max() > 3.0 and altitude[-1] < 0.05  # it flew up on the plugged law, then landed


def plugged_spec(tmp_path: Path, extra: str = "", controller: str = TEMPLATE) -> Path:
    path = tmp_path / "plugged.toml"
    path.write_text(textwrap.dedent(f"""\
        preset = "x500"
        controller = "{controller}"
        trajectory = "hold:altitude=3,duration=4"
        trials = 2
        seed = 46
        [vary]
        mismatch.mass = {{ dist = "uniform", low = 0.9, high = 1.1 }}
        {extra}"""), encoding="utf-8")  # fmt: skip
    return path


@pytest.mark.parametrize("controller", [TEMPLATE, "px4"], ids=["template", "px4"])
def test_a_sweep_flies_a_plugged_controller_trial_by_trial_as_sim_does(tmp_path, controller):
    from groundstation.offline import telemetry_rows
    from groundstation.sweep import engine
    from groundstation.sweep.run import fly
    from groundstation.sweep.spec import load_spec
    from groundstation.sweep.trial_row import metrics_row
    from groundstation.sweep.trials import trial_preset

    spec = load_spec(str(plugged_spec(tmp_path, controller=controller)))
    assert not spec.fused and spec.controller == controller
    res = fly(spec, [0, 1])
    for k in (0, 1):
        preset = trial_preset(spec, k)
        assert preset.controller.type == controller  # `sim --from-sweep` flies the same controller
        sims, _ = run_offline(preset, [spec.controller], spec.duration, trajectory=spec.trajectory)
        sim = sims[spec.controller]
        want = metrics_row(telemetry_rows(sim, rates=False), preset, spec.period, sim.diverged_at, False)
        assert np.array_equal(res.metrics[k], want, equal_nan=True)
    tracking = res.metrics[:, [engine.METRICS.index(n) for n in engine.POSITION_METRICS]]
    assert np.isfinite(tracking).all() and (tracking[:, :2] < 0.1).all()  # the hold; altitude_rms has the climb
    assert (res.metrics[:, engine.M_DIVERGED] == 0.0).all() and res.metrics[0, engine.M_ALTITUDE_RMS] != res.metrics[
        1, engine.M_ALTITUDE_RMS
    ]  # each trial its own mass mismatch
    assert res.metrics[0, engine.M_TICKS] == spec.ticks


def test_a_sweep_refuses_gains_of_a_plugged_controller_and_a_broken_one_in_one_line(tmp_path):
    from groundstation.sweep.spec import load_spec
    from quadsitl.config import ConfigError

    with pytest.raises(ConfigError, match=r"vary.gains.k1: gains.\* are the built-in controllers'") as err:
        load_spec(str(plugged_spec(tmp_path, 'gains.k1 = { dist = "uniform", low = 1.0, high = 2.0 }')))
    assert "\n" not in str(err.value)
    broken = tmp_path / "broken.toml"
    broken.write_text('preset = "x500"\ncontroller = "nowhere.py:C"\ntrajectory = "hold"\n', encoding="utf-8")
    with pytest.raises(ConfigError, match=r"controller .*nowhere.py:C: no such file") as err:
        load_spec(str(broken))
    assert "\n" not in str(err.value)


def test_controller_params_reach_the_flight_and_are_checked_in_one_line(tmp_path):
    """``--controller-param NAME=VALUE`` (by name or MAVLink name) flies the value, says so in metrics.json, and is
    refused in one line when malformed, out of range, unknown, or given to a built-in controller."""
    import json

    def sim(*args: str, out: str = "run") -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "groundstation.cli", "sim", "--preset", "x500", "--trajectory",
                               "circle:radius=3,period=8,hold=1", "--no-figures", "-q", "--out", str(tmp_path / out),
                               *args], capture_output=True, text=True, timeout=300)  # fmt: skip

    assert sim("--controller", "px4", out="default").returncode == 0
    r = sim("--controller", "px4", "--controller-param", "MPC_XY_P=1.5", "--controller-param", "mc_yaw_p=2")
    assert r.returncode == 0, r.stderr
    report = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert report["controller_params"] == {"MPC_XY_P": 1.5, "mc_yaw_p": 2.0}
    stiffer, default = (json.loads((tmp_path / d / "metrics.json").read_text())["position"]["px4"]["horizontal_rms"]
                        for d in ("run", "default"))  # fmt: skip
    assert stiffer < default  # a stiffer position loop tracks the circle closer
    for args, says in ((("--controller", "px4", "--controller-param", "MPC_XY_P=9"), "MPC_XY_P = 9.0: expected a "
                        "number in [0, 2] 1/s"),
                       (("--controller", "px4", "--controller-param", "NOPE=1"), "no parameter 'NOPE'"),
                       (("--controller", "px4", "--controller-param", "MPC_XY_P"), "expected NAME=VALUE"),
                       (("--controller-param", "kp=1",), "only a controller that plugs in")):  # fmt: skip
        r = sim(*args, out="refused")
        lines = r.stderr.strip().splitlines()
        assert r.returncode == 2 and len(lines) == 1 and says in lines[0], r.stderr
        assert not (tmp_path / "refused").exists()


def test_sweep_controller_flies_the_spec_with_another_controller_and_writes_what_it_flew(tmp_path):
    """``quadsitl sweep SPEC --controller examples/...:Template`` (a path from the working directory): the spec it
    writes names the controller by its absolute path, and ``sim --from-sweep`` flies a trial again with it, to the
    row."""
    import json

    out = tmp_path / "sweep"
    cmd = [sys.executable, "-m", "groundstation.cli"]
    relative = "examples/controllers/template.py:Template"
    r = subprocess.run([*cmd, "sweep", "paper-mass-mismatch", "--controller", relative, "--trials", "4",
                        "--no-figures", "-q", "--out", str(out)], cwd=ROOT, capture_output=True, text=True,
                       timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert f'controller = "{TEMPLATE}"' in (out / "spec.toml").read_text()
    again = tmp_path / "again"
    r = subprocess.run([*cmd, "sim", "--from-sweep", str(out), "--trial", "2", "--no-figures", "-q", "--out",
                        str(again)], capture_output=True, text=True, timeout=300)  # fmt: skip
    assert r.returncode == 0, r.stderr
    report = json.loads((again / "metrics.json").read_text())
    assert list(report["runs"]) == [TEMPLATE]
