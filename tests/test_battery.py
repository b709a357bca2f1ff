"""The battery (sitl/battery.py, docs/battery.md): the power the motors draw, the pack's voltage and current, the
charge and energy drawn, an empty pack stopping the motors, the ideal supply of a preset without [battery], and the
[battery] section's refusals."""

import dataclasses
import json
import math

import numpy as np
import pytest

from autopilot import plant_messages
from autopilot.commander import (
    BAT_WARNING,
    FAILSAFE,
    FAILSAFE_BATTERY,
    Commander,
    CommanderSettings,
    battery_seen,
)
from quadsitl import codec, hil, wire
from quadsitl.config import ConfigError, load_preset, parse_preset, preset_toml
from quadsitl.state import VehicleState
from quadsitl.wire import Mode, mavlink
from sitl.plant import OUT_CHARGE, OUT_CURRENT, OUT_ENERGY, Plant

X500 = load_preset("x500")
HOVER = X500.vehicle.mass * X500.vehicle.gravity / 4  # [N] per motor


def with_battery(preset, **keys):
    return dataclasses.replace(preset, battery=dataclasses.replace(preset.battery, **keys))


def expected_current(preset, forces, charge):
    """The current [A] the docs' equations give, worked out here by hand: shaft power d·Ω³ per motor, the pack's
    linear open-circuit voltage, the smaller root of (V_oc − R·I)·I = P."""
    v, b = preset.vehicle, preset.battery
    shafts = sum(v.drag_factor * math.sqrt(abs(f) / v.thrust_factor) ** 3 for f in forces)
    p = shafts / b.efficiency + b.avionics_w
    s = b.remaining - charge / (b.capacity_mah * 3.6)
    voc = b.cells * (b.v_empty + (b.v_full - b.v_empty) * s)
    r = b.cells * b.cell_resistance_ohm
    return (voc - math.sqrt(voc * voc - 4 * r * p)) / (2 * r), voc, r, p


def settled(preset, forces=(HOVER,) * 4):
    """A plant whose motors have spun up to ``forces`` (their lag) and whose battery is then as new."""
    plant = Plant(preset)
    for _ in range(500):
        plant.step(forces)
    plant.out[OUT_CHARGE] = plant.out[OUT_ENERGY] = 0.0
    return plant


def test_a_hovering_x500_draws_the_power_its_rotors_need_at_the_pack_voltage():
    plant = settled(X500)
    plant.step((HOVER,) * 4)
    assert plant.forces == pytest.approx((HOVER,) * 4)
    current, voc, r, p = expected_current(X500, plant.forces, 0.0)
    assert plant.out[OUT_CURRENT] == pytest.approx(current, rel=1e-12)
    assert (voc - r * current) * current == pytest.approx(p, rel=1e-12)  # the power reaches the terminals
    assert 15.0 < current < 25.0  # a 2 kg quadrotor on 4 cells hovers on some 300 W
    assert plant.out[OUT_CHARGE] == pytest.approx(current * X500.sim.period)
    assert plant.out[OUT_ENERGY] == pytest.approx((voc - r * current) * current * X500.sim.period)


def test_the_charge_and_energy_drawn_add_up_and_the_current_rises_as_the_voltage_falls():
    preset = with_battery(X500, capacity_mah=100.0)
    plant = settled(preset)
    charge = energy = 0.0
    currents = []
    for k in range(3000):
        forces = (HOVER + math.sin(k / 100.0),) * 2 + (HOVER - math.sin(k / 100.0),) * 2
        plant.step(forces)
        i0, voc, r, _ = expected_current(preset, plant.forces, charge)
        assert plant.out[OUT_CURRENT] == pytest.approx(i0, rel=1e-12)
        charge += i0 * X500.sim.period
        energy += (voc - r * i0) * i0 * X500.sim.period
        currents.append(plant.out[OUT_CURRENT])
    assert plant.out[OUT_CHARGE] == pytest.approx(charge, rel=1e-9)
    assert plant.out[OUT_ENERGY] == pytest.approx(energy, rel=1e-9)
    steady = settled(preset)
    before = steady.out[OUT_CURRENT]
    for _ in range(3000):
        steady.step((HOVER,) * 4)
    assert steady.out[OUT_CURRENT] > before * 1.005  # the same power at a lower voltage: more current


def test_an_empty_battery_stops_the_motors_and_the_vehicle_falls():
    preset = with_battery(X500, capacity_mah=20.0, remaining=0.5)  # 10 mAh: about 2 s of hover
    plant = Plant(dataclasses.replace(preset, initial=dataclasses.replace(preset.initial, altitude=30.0)))
    hover_ticks = 0
    while plant.out[OUT_CHARGE] < 10 * 3.6 and hover_ticks < 10_000:
        plant.step((HOVER,) * 4)
        hover_ticks += 1
    current, *_ = expected_current(preset, (HOVER,) * 4, 0.0)  # at half charge; the most, when empty:
    most, *_ = expected_current(preset, (HOVER,) * 4, 10 * 3.6 * (1 - 1e-9))
    assert 10 * 3.6 / most < hover_ticks * X500.sim.period < 10 * 3.6 / current + 0.1  # + the motors' spin-up
    assert plant.state.z == pytest.approx(-30.0, abs=0.3)  # it hovered while there was charge (less the spin-up)
    for _ in range(1000):
        plant.step((HOVER,) * 4)
    assert plant.out[OUT_CURRENT] == 0.0
    assert plant.out[OUT_CHARGE] == pytest.approx(10 * 3.6, abs=current * X500.sim.period)
    assert max(plant.motors) < 0.01 * HOVER  # spun down with their lag
    assert plant.state.vz > 5.0  # falling, 1 s after the motors stopped
    assert plant.state.z > -30.0 + 3.0


def test_a_preset_without_a_battery_section_flies_on_an_ideal_supply():
    paper = load_preset("paper")
    assert paper.battery is None
    plant = Plant(paper)
    for _ in range(100):
        plant.step((10.0,) * 4)
    assert (plant.out[OUT_CURRENT], plant.out[OUT_CHARGE], plant.out[OUT_ENERGY]) == (0.0, 0.0, 0.0)
    x500_ideal = Plant(dataclasses.replace(X500, battery=None))
    x500 = Plant(X500)
    for _ in range(500):
        x500_ideal.step((6.0,) * 4)
        x500.step((6.0,) * 4)
    assert x500.state == x500_ideal.state  # until it is empty the battery changes nothing of the flight


def test_a_battery_section_reads_back_from_its_toml_and_is_checked():
    assert parse_preset(preset_toml(X500)).battery == X500.battery
    text = preset_toml(X500)
    with pytest.raises(ConfigError, match=r"battery.v_empty = 4.3: must be below battery.v_full = 4.2"):
        parse_preset(text.replace("v_empty = 3.5", "v_empty = 4.3"))
    with pytest.raises(ConfigError, match=r"battery.cell_resistance_ohm = 0.2: an empty pack of 4 cells gives at most "
                       r"61.25 W .* 688.9 W; allowed: below 0.01778 Ω per cell"):  # fmt: skip
        parse_preset(text.replace("cell_resistance_ohm = 0.005", "cell_resistance_ohm = 0.2"))
    with pytest.raises(ConfigError, match=r"battery.cells = 4.5: expected an integer in \[1, 14\]"):
        parse_preset(text.replace("cells = 4", "cells = 4.5"))
    with pytest.raises(ConfigError, match=r"missing key battery.capacity_mah \(a number in \(0, 1e6\] mAh\)"):
        parse_preset(text.replace("capacity_mah = 5000.0\n", ""))
    with pytest.raises(ConfigError, match=r"unknown key battery.voltage; allowed in \[battery\]: capacity_mah"):
        parse_preset(text.replace("[battery]\n", "[battery]\nvoltage = 12.0\n"))
    with pytest.raises(ConfigError, match=r"battery.remaining = 0.0: expected a number in \(0, 1\]"):
        parse_preset(text.replace("remaining = 1.0", "remaining = 0.0"))


# ---- the commander: PX4's warning levels and COM_LOW_BAT_ACT ----------------------------------------------------


def reporting(remaining: float, **settings) -> Commander:
    """A commander whose battery reports ``remaining`` (0..1), with ``settings`` over the defaults."""
    c = Commander(CommanderSettings(**settings))
    battery_seen(c.cm, (15.0, 18.0, 1000.0, 5e4, remaining))
    return c


def tick(c: Commander, k: int, remaining: float, altitude: float = 5.0) -> None:
    c.messages.clear()
    battery_seen(c.cm, (15.0, 18.0, 1000.0, 5e4, remaining))
    c.update(k, k * 0.001, VehicleState(z=-altitude))


def flying(remaining: float = 0.5, **settings) -> Commander:
    c = reporting(remaining, **settings)
    c.update(0, 0.0, VehicleState(z=-5.0))
    assert c.arm() == (True, "")
    c.set_mode(Mode.MISSION)
    tick(c, 1, remaining)  # above AIRBORNE_ALT: taken off
    return c


@pytest.mark.parametrize(
    ("action", "critical", "emergency"),
    [(0, Mode.MISSION, Mode.MISSION), (1, Mode.RTL, Mode.RTL), (2, Mode.LAND, Mode.LAND), (3, Mode.RTL, Mode.LAND)],
)
def test_each_new_battery_level_takes_com_low_bat_act_as_px4(action, critical, emergency):
    c = flying(low_bat_action=action)
    tick(c, 2, 0.149)
    assert c.messages == [(4, "Battery low: 15% remaining")] and c.mode == Mode.MISSION
    tick(c, 3, 0.13)
    assert c.messages == []  # the same level: said once
    tick(c, 4, 0.069)
    taken = {0: "warning", 1: "return", 2: "land", 3: "return"}[action]
    assert c.messages == [(2, f"Battery critical: 7% remaining; action: {taken}")]
    assert c.mode == critical and c.cm[FAILSAFE] == (FAILSAFE_BATTERY if action else 0)
    tick(c, 5, 0.049)
    taken = {0: "warning", 1: "return", 2: "land", 3: "land"}[action]
    going_on = action == 2  # already landing since the critical level
    assert c.messages == [(1, f"Battery emergency: 5% remaining; action: {taken}")]
    assert c.mode == emergency and c.armed
    assert going_on or action == 0 or c.cm[FAILSAFE] == FAILSAFE_BATTERY


def test_armed_the_level_only_rises_and_a_level_already_there_at_arming_takes_no_action():
    c = flying(0.10, low_bat_action=2)  # low at arming: armed, the low level counts as the one at arming
    tick(c, 2, 0.20)  # a recovering voltage does not lower the level in flight
    assert c.cm[BAT_WARNING] == 1 and c.messages == []
    tick(c, 3, 0.06)
    assert c.mode == Mode.LAND  # critical is worse than at arming: the action
    c.disarm()
    tick(c, 4, 0.20)
    assert c.cm[BAT_WARNING] == 0  # disarmed, the level follows the battery


def test_arming_is_denied_on_a_critical_battery_and_a_return_lands_at_emergency():
    c = reporting(0.06)
    c.update(0, 0.0, VehicleState())
    assert c.arm() == (False, "Arming denied: low battery, 6% remaining (BAT_CRIT_THR 7%)") and not c.armed
    c = reporting(0.06, bat_crit_thr=0.05)  # below 7% but above the critical threshold set
    c.update(0, 0.0, VehicleState())
    assert c.arm() == (True, "")
    c = flying(low_bat_action=3)
    c.set_mode(Mode.RTL)
    tick(c, 2, 0.06)
    assert c.mode == Mode.RTL and c.messages == [(2, "Battery critical: 6% remaining; action: return")]
    tick(c, 3, 0.04)
    assert c.mode == Mode.LAND and c.messages == [(1, "Battery emergency: 4% remaining; action: land")]
    c = flying(low_bat_action=1)
    c.set_mode(Mode.LAND)
    tick(c, 2, 0.06)
    assert c.mode == Mode.LAND
    assert c.messages == [(2, "Battery critical: 6% remaining; action: return, not taken: land goes on")]


def test_no_battery_no_level_and_on_the_ground_a_warning_only():
    c = Commander(CommanderSettings(low_bat_action=2))  # no report: an ideal supply
    c.update(0, 0.0, VehicleState())
    assert c.arm() == (True, "")
    c.update(1, 0.001, VehicleState(z=-5.0))
    assert c.cm[BAT_WARNING] == 0 and c.messages[-1] == (6, "Armed")
    c = reporting(0.5, low_bat_action=2)
    c.update(0, 0.0, VehicleState())
    assert c.arm() == (True, "")
    tick(c, 1, 0.06, altitude=0.0)  # armed on the ground, not taken off: said, not flown
    assert c.mode == Mode.HOLD and c.messages == [(2, "Battery critical: 6% remaining; action: warning")]


# ---- the wire: the plant's BATTERY_STATUS ---------------------------------------------------------------------


@pytest.mark.parametrize(
    ("voltage", "current", "charge", "energy", "remaining", "cells"),
    [(16.8, 0.0, 0.0, 0.0, 1.0, (16800, 65535)), (14.2137, 18.3849, 3600.0 * 1.2345, 123456.7, 0.4949, (14214, 65535)),
     (70.0, 120.0, 1e5, 9e6, 0.004, (65534, 4466, 65535)), (15.0, 400.0, 0.0, 0.0, 0.0, (15000, 65535))],
)  # fmt: skip
def test_the_plants_battery_status_is_pymavlinks_and_reads_back_in_px4s_units(
    voltage, current, charge, energy, remaining, cells
):
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    n = hil.encode_battery(buf, 7, 1, 200, voltage, current, charge, energy, remaining)
    (msg,) = wire.link(1, 1).parse_buffer(buf[:n].tobytes())
    cells_sent = [*cells[:-1], *[65535] * (10 - len(cells) + 1)]
    assert list(msg.voltages) == cells_sent  # the pack in the first cell, the rest past 65.534 V in the next
    assert msg.current_battery == min(round(current * 100), 32767)
    assert (msg.current_consumed, msg.energy_consumed) == (round(charge / 3.6), round(energy / 100))
    assert msg.battery_remaining == round(remaining * 100)
    assert (msg.temperature, msg.battery_function, msg.type) == (32767, 1, 1)  # unknown; all; LiPo
    ref = mavlink.MAVLink_battery_status_message(
        0,
        1,
        1,
        32767,
        cells_sent,
        msg.current_battery,
        msg.current_consumed,
        msg.energy_consumed,
        msg.battery_remaining,
        0,
        0,
        [0] * 4,
        0,
        0,
    )
    mav = wire.link(1, 200)
    mav.seq = 7
    assert buf[:n].tobytes() == ref.pack(mav)  # byte for byte pymavlink's frame
    frame = np.zeros(codec.FRAME_MAX, dtype=np.uint8)
    frame[: n - 2] = buf[: n - 2]  # the payload zero-padded, as the decoders' frame checks leave it
    got = hil.decode_battery(frame)
    assert got == pytest.approx((sum(cells[:-1]) / 1000, msg.current_battery / 100, msg.current_consumed,
                                 msg.energy_consumed * 100.0, msg.battery_remaining / 100))  # fmt: skip


def test_a_battery_status_stays_with_its_state_on_the_pymavlink_path():
    state = wire.link(1, wire.PLANT_COMPONENT_ID)
    buf = np.zeros(hil.DATAGRAM_MAX, dtype=np.uint8)
    n = codec.encode_state(buf, 0, 1, wire.PLANT_COMPONENT_ID, 1000, np.zeros(12))
    n += hil.encode_battery(buf[n:], 1, 1, wire.PLANT_COMPONENT_ID, 16.0, 2.0, 36.0, 500.0, 0.9)
    text = mavlink.MAVLink_statustext_message(4, b"hello", 0, 0).pack(state)  # not per-tick: pymavlink sorts it out
    sorted_out = plant_messages.sort_out(wire.link(1, 1), buf[:n].tobytes() + text, sensing=False)
    (datagram,) = sorted_out.datagrams  # the state with its battery, as one datagram to fly
    sent, flown = wire.link(1, 1).parse_buffer(buf[:n].tobytes()), wire.link(1, 1).parse_buffer(datagram)
    assert [m.get_type() for m in flown] == ["ODOMETRY", "BATTERY_STATUS"]
    assert flown[1].to_dict() == sent[1].to_dict() and flown[0].time_usec == sent[0].time_usec == 1000
    assert sorted_out.said == (4, "hello")


# ---- what a flight drew: telemetry.csv, metrics.json ---------------------------------------------------------


def test_sims_files_carry_the_battery_for_an_x500_and_nothing_for_the_paper(tmp_path):
    from groundstation.offline import run_offline, write_outputs
    from groundstation.telemetry_csv import BATTERY_COLUMNS, COLUMNS, read_csv

    for name in ("x500", "paper"):
        preset = load_preset(name)
        results, metrics = run_offline(preset, ["backstepping"], 2.0)
        out = tmp_path / name
        write_outputs(out, preset, results, metrics, {}, figures=False)
        csv = read_csv(out / "telemetry.csv")
        report = json.loads((out / "metrics.json").read_text())
        if name == "paper":
            assert tuple(csv) == COLUMNS and "battery" not in report
            continue
        assert tuple(csv)[-5:] == BATTERY_COLUMNS
        used = report["battery"]
        assert used["energy_j"] == pytest.approx(csv["battery_j"][-1] - csv["battery_j"][0])
        assert 400.0 < used["energy_j"] < 1000.0  # 2 s of a climb to 2 m on some 300 W, in steps of 100 J
        assert used["remaining_start"] == 1.0 and used["remaining_end"] == 1.0  # 0.2 % of 5000 mAh: rounds to 100 %
        assert 15.0 < used["voltage_min_v"] < 16.8 and 15.0 < used["current_max_a"] < 60.0
