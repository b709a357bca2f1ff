"""A plugged controller (examples/controllers/template.py) in the processes: ``fly`` flies what ``sim`` flies, to the
float32 of the wire, and ``up`` flies it for MAVSDK (takeoff, goto, return) with its parameters served as MAVLink
parameters, checked against their ranges and the controller's own check."""

from __future__ import annotations

import asyncio
import json
import subprocess

import pytest
from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError

from autopilot.params import PLUGGED_TYPE, ParamStore
from autopilot.plugin import load
from quadsitl.config import load_preset
from tests.mavclient import quadsitl_up
from tests.mavsdk_client import autopilot
from tests.test_fly import quadsitl
from tests.test_plugged import TEMPLATE, controller_file
from tests.test_position_mavsdk import SPEED, takeoff_goto_return
from tests.test_vehicle import assert_float32_equal, run


@pytest.mark.parametrize("controller", [TEMPLATE, "px4"], ids=["template", "px4"])
def test_fly_equals_sim_with_a_plugged_controller(tmp_path, controller):
    circle = ("--preset", "x500", "--controller", controller, "--trajectory", "circle:radius=3,period=8,hold=1")
    fly, sim = run(tmp_path, "fly", "fly", *circle), run(tmp_path, "sim", "sim", *circle)
    assert_float32_equal(fly, sim, ("x", "y", "altitude", "yaw", "x_ref", "y_ref", "altitude_ref"), 1e-5)
    assert_float32_equal(fly, sim, ("u1", "f1", "f2", "f3", "f4"), 1e-3)
    report = json.loads((tmp_path / "fly" / "metrics.json").read_text())
    # flown, not only equal: this circle is fast (2.4 m/s on 3 m), which PX4's soft defaults trail by about a metre
    assert report["position"][next(iter(report["position"]))]["horizontal_rms"] < 1.5


def test_fly_refuses_a_broken_controller_before_starting_anything(tmp_path):
    path = controller_file(tmp_path, "class C(Controller):\n    parameters = (Parameter('kp', 1.0, '', 0.0, 2.0, "
                                     "'a gain', 'lowercase'),)\n")  # fmt: skip
    r = subprocess.run(quadsitl("fly", "--preset", "x500", "--controller", f"{path}:C", "--out", str(tmp_path / "o")),
                       capture_output=True, text=True, timeout=120)  # fmt: skip
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert "expected a @staticmethod law" in r.stderr  # the first thing wrong with it


def test_the_plugged_parameters_are_parameters_of_the_autopilot():
    x500 = load_preset("x500")
    from autopilot.commander import CommanderSettings

    store = ParamStore(x500, TEMPLATE, CommanderSettings(), load(TEMPLATE))
    assert store.lookup("CTL_TYPE")[2] == PLUGGED_TYPE and store.lookup("KP_XY")[2] == 4.0
    assert store.lookup("TPL_MAX_TILT")[2] == 0.6  # a MAVLink name of its own
    assert store.lookup(index=len(store) - 1)[1] == "TPL_MAX_TILT"  # after the autopilot's own, in order
    assert store.set("KP_XY", 2.5) == "" and store.applied().plugged["kp_xy"] == 2.5
    assert store.set("KP_XY", 80.0) == "KP_XY = 80: expected a number in [0, 50] 1/s²"
    assert "must exceed ki_z" in store.set("KI_Z", 19.0)  # the template's own check: kv_z·kp_z = 16
    assert store.lookup("KI_Z")[2] == 0.5  # refused: unchanged
    assert store.set("CTL_TYPE", 1.0) == "" and store.applied().controller == "pd"
    assert store.set("CTL_TYPE", 2.0) == "" and store.applied().controller == TEMPLATE


async def params_then_fly(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        param = ParamAsync(system)
        seen["KP_XY"] = await param.get_param_float("KP_XY")
        try:
            await param.set_param_float("KV_XY", 500.0)
            seen["refused"] = False
        except ParamError:
            seen["refused"] = True
        await param.set_param_float("KV_XY", 5.0)
        seen["KV_XY"] = await param.get_param_float("KV_XY")
    seen.update(await takeoff_goto_return(port))
    return seen


def test_up_flies_the_template_for_mavsdk():
    with quadsitl_up("--preset", "x500", "--controller", TEMPLATE, "--speed", SPEED) as v:
        seen = asyncio.run(asyncio.wait_for(params_then_fly(v.api_port), 200))
        assert v.proc.poll() is None
    assert seen["KP_XY"] == 4.0 and seen["refused"] and seen["KV_XY"] == 5.0
    assert seen["altitude"] == pytest.approx(5.0, abs=0.3)
    assert seen["arrived"][:2] == pytest.approx((20.0, 0.0), abs=0.5)
    assert seen["held"] == pytest.approx((20.0, 0.0, 5.0), abs=0.3)
    assert seen["disarmed"] is False and seen["landed_at"][2] < 0.1


async def px4_params_then_fly(port: int) -> dict:
    seen: dict = {}
    async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as m:
        system = await autopilot(m, port)
        param = ParamAsync(system)
        seen["MPC_XY_P"] = await param.get_param_float("MPC_XY_P")
        seen["MC_ROLLRATE_P"] = await param.get_param_float("MC_ROLLRATE_P")
        try:
            await param.set_param_float("MPC_THR_HOVER", 0.05)  # outside PX4's range, [0.1, 0.8]
            seen["refused"] = False
        except ParamError:
            seen["refused"] = True
    seen.update(await takeoff_goto_return(port))
    return seen


def test_up_flies_px4s_cascade_for_mavsdk_with_px4s_parameter_names():
    with quadsitl_up("--preset", "x500", "--controller", "px4", "--controller-param", "mpc_xy_p=1.2", "--speed",
                     SPEED) as v:  # fmt: skip
        seen = asyncio.run(asyncio.wait_for(px4_params_then_fly(v.api_port), 200))
        assert v.proc.poll() is None
    assert seen["MPC_XY_P"] == pytest.approx(1.2) and seen["MC_ROLLRATE_P"] == pytest.approx(0.15)
    assert seen["refused"]
    assert seen["altitude"] == pytest.approx(5.0, abs=0.3)
    assert seen["arrived"][:2] == pytest.approx((20.0, 0.0), abs=0.5)
    assert seen["disarmed"] is False and seen["landed_at"][2] < 0.1
