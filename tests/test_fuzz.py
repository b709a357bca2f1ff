"""Hostile input while the vehicle holds its position: 100,000 random and mutated datagrams at every UDP port of
the autopilot and the plant (among them position targets in every frame, takeoff, reposition, speed and mode
commands, and the mission protocol's messages), and garbage over TCP at the autopilot's Zenoh listener.
Nothing crashes, no exception escapes a loop, the state stays finite, the vehicle holds its position within
0.1 m, and the refusals are counted in SYS_STATUS."""

import contextlib
import math
import os
import random
import socket
import subprocess
import sys
import time

import pytest
from pymavlink.dialects.v20 import common as M  # noqa: N812 (the MAVLink constants, short)

from groundstation.launcher import free_port
from quadsitl.process_util import free_ports_apart
from quadsitl.wire import link
from tests.mavclient import Client

HOSTILE_FLOATS = (math.nan, math.inf, -math.inf, 1e30, -1e30, 3.4e38, -3.4e38, 123456.75, -98765.5)
# Commands that are valid whatever their parameters carry authority, not hostile values (signing is the
# defence against strangers who send them): a fuzzer that sends NAV_LAND lands the vehicle, as it should.
# DO_REPOSITION stays in: its random locations lie beyond the geofence the test sets (GF_MAX_HOR_DIST).
AUTHORITY = {M.MAV_CMD_NAV_LAND, M.MAV_CMD_NAV_RETURN_TO_LAUNCH}
TARGETED = [
    M.MAVLink_command_long_message, M.MAVLink_command_int_message, M.MAVLink_set_attitude_target_message,
    M.MAVLink_set_position_target_local_ned_message, M.MAVLink_set_position_target_global_int_message,
    M.MAVLink_set_mode_message, M.MAVLink_param_set_message, M.MAVLink_param_request_read_message,
    M.MAVLink_mission_count_message, M.MAVLink_mission_item_int_message, M.MAVLink_mission_item_message,
    M.MAVLink_mission_request_list_message, M.MAVLink_mission_request_int_message, M.MAVLink_mission_ack_message,
    M.MAVLink_mission_clear_all_message, M.MAVLink_mission_set_current_message,
    M.MAVLink_param_request_list_message, M.MAVLink_file_transfer_protocol_message, M.MAVLink_heartbeat_message,
    M.MAVLink_odometry_message, M.MAVLink_hil_actuator_controls_message, M.MAVLink_statustext_message,
]  # fmt: skip
HOLD = (4 << 16) | (3 << 24)  # PX4's AUTO.LOITER
ALL = [c for c in vars(M).values() if isinstance(c, type) and issubclass(c, M.MAVLink_message) and hasattr(c, "id")]


def hostile_message(rng: random.Random):
    cls = rng.choice(TARGETED) if rng.random() < 0.8 else rng.choice(ALL)
    lengths = dict(zip(cls.ordered_fieldnames, cls.lengths))
    args = []
    for name, ftype in zip(cls.fieldnames, cls.fieldtypes):
        n = lengths.get(name, 1)
        if name in ("target_system",):
            value = rng.choice([1, 1, 1, 0, 7])
        elif name in ("target_component",):
            value = rng.choice([1, 1, 0, 190])
        elif name == "coordinate_frame":
            value = rng.choice([1, 8, 5, 6, 11, rng.randrange(256)])
        elif name == "type_mask":
            value = rng.choice([2552, 2503, 2496, 2048, 3135, 1479, 512 | 2048, rng.randrange(65536)])
        elif name == "command":
            value = rng.choice(
                [
                    c
                    for c in (400, 176, 512, 511, 510, 520, 410, 22, 192, 178, rng.randrange(65536))
                    if c not in AUTHORITY
                ]
            )
        elif name == "param_id":
            value = rng.choice(
                [b"BS_K1", b"VM_MASS", b"CTL_TYPE", b"SP_ALT_MAX", bytes(rng.randrange(256) for _ in range(16))]
            )
        elif ftype == "char":
            value = bytes(rng.randrange(256) for _ in range(rng.randrange(n + 1)))
            args.append(value)
            continue
        elif ftype in ("float", "double"):
            value = [rng.choice(HOSTILE_FLOATS) for _ in range(n)] if n > 1 else rng.choice(HOSTILE_FLOATS)
        else:
            bits = {"uint8_t": 8, "int8_t": 8, "uint16_t": 16, "int16_t": 16, "uint32_t": 32, "int32_t": 32}.get(
                ftype, 64
            )
            lo, hi = (-(2 ** (bits - 1)), 2 ** (bits - 1) - 1) if ftype.startswith("int") else (0, 2**bits - 1)
            value = [rng.randint(lo, hi) for _ in range(n)] if n > 1 else rng.randint(lo, hi)
        args.append(value)
    return cls(*args)  # fmt: skip


def datagrams(rng: random.Random, count: int) -> list[bytes]:
    """Valid frames with hostile field values, mutated frames, truncated frames and garbage."""
    mav = link(rng.randrange(1, 256), rng.randrange(256))
    out: list[bytes] = []
    while len(out) < count:
        kind = rng.random()
        if kind < 0.1:
            out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))))
            continue
        try:
            frame = hostile_message(rng).pack(mav)
        except Exception:  # a value pymavlink cannot pack (e.g. a float where it checks): try another
            continue
        if kind < 0.55:
            out.append(frame)
        elif kind < 0.75:
            b = bytearray(frame)
            for _ in range(rng.randrange(1, 4)):
                b[rng.randrange(len(b))] = rng.randrange(256)
            out.append(bytes(b))
        elif kind < 0.9:
            out.append(frame[: rng.randrange(1, len(frame))])
        else:
            out.append(frame + frame[: rng.randrange(len(frame))])  # one and a half frames
    return out


@pytest.fixture
def flying_vehicle():
    ports = dict(zip(("plant_listen", "gcs", "api", "plant_bind"), free_ports_apart(4), strict=True))
    ports["zenoh"] = free_port(socket.SOCK_STREAM)
    ap = subprocess.Popen([sys.executable, "-m", "autopilot", "--zenoh-listen", f"tcp/127.0.0.1:{ports['zenoh']}",
                           "--plant-listen",
                           f"127.0.0.1:{ports['plant_listen']}", "--gcs-listen", f"127.0.0.1:{ports['gcs']}",
                           "--gcs-remote", "none", "--api-listen", f"127.0.0.1:{ports['api']}", "--api-remote", "none"],
                          stderr=subprocess.PIPE, text=True)  # fmt: skip
    plant = subprocess.Popen([sys.executable, "-m", "sitl", "--autopilot", f"127.0.0.1:{ports['plant_listen']}",
                              "--bind", f"127.0.0.1:{ports['plant_bind']}", "--speed", "1"],
                             stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        yield ap, plant, ports
    finally:
        for p in (plant, ap):
            if p.poll() is None:
                p.terminate()
        for p in (plant, ap):
            try:
                p.wait(5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def test_100k_hostile_datagrams_while_flying(flying_vehicle):
    ap, plant, ports = flying_vehicle
    c = Client.to(ports["api"])
    try:
        c.connect()
        c.param_set("GF_MAX_HOR_DIST", 50.0)  # a geofence: random goto locations are refused, not flown
        c.param_set("MIS_TAKEOFF_ALT", 2.0)
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        nan = math.nan
        assert c.command(M.MAV_CMD_NAV_TAKEOFF, nan, nan, nan, nan, nan, nan, nan).result == M.MAV_RESULT_ACCEPTED
        c.wait("HEARTBEAT", lambda m: m.custom_mode == HOLD, timeout=15)  # takeoff done: holding
        c.pump(2.0)
        held = c.latest["LOCAL_POSITION_NED"]
        assert (held.x, held.y, held.z) == pytest.approx((0.0, 0.0, -2.0), abs=0.02)

        rng = random.Random(int(os.environ.get("QUADSITL_FUZZ_SEED", "20261123")))
        pool = datagrams(rng, 5000)
        targets = [("127.0.0.1", ports[k]) for k in ("api", "gcs", "plant_listen", "plant_bind")]
        fuzz = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sent, t0 = 0, time.monotonic()
        while sent < 100_000:
            for _ in range(200):
                fuzz.sendto(pool[rng.randrange(len(pool))], targets[sent % len(targets)])
                sent += 1
            c.pump(0.005)  # ~40,000 datagrams/s, while the real GCS keeps listening
            if ap.poll() is not None or plant.poll() is not None:
                dead = ap if ap.poll() is not None else plant
                pytest.fail(f"{dead.args[2]} died under fuzzing:\n{dead.stderr.read()[-3000:]}")
        fuzz.close()
        # The Zenoh listener is a listening port too: garbage over TCP, 200 connections.
        for i in range(200):
            with (
                socket.create_connection(("127.0.0.1", ports["zenoh"]), timeout=2) as tcp,
                contextlib.suppress(OSError),
            ):
                tcp.sendall(pool[i] * 3)
        fuzz_seconds = time.monotonic() - t0
        c.pump(3.0)
        att, pos, hb = c.latest["ATTITUDE"], c.latest["LOCAL_POSITION_NED"], c.latest["HEARTBEAT"]
        status = c.latest["SYS_STATUS"]
    finally:
        c.conn.close()

    assert ap.poll() is None and plant.poll() is None
    values = (att.roll, att.pitch, att.yaw, att.rollspeed, pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz)
    assert all(map(math.isfinite, values))
    assert hb.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED and hb.custom_mode == HOLD  # still holding
    assert math.hypot(pos.x - held.x, pos.y - held.y, pos.z - held.z) < 0.1
    # counted, not silent: bad frames, unknown messages, refused inputs, plant-link strangers, other targets
    assert status.errors_comm > 100 and status.errors_count1 > 100 and status.errors_count2 > 100
    assert status.errors_count3 > 100 and status.errors_count4 > 100
    assert fuzz_seconds < 60
    for p in (ap, plant):
        p.terminate()
        _, err = p.communicate(timeout=10)
        assert "Traceback" not in err and "error: handling" not in err, err[-2000:]


def upload(c: Client, points: list[tuple[float, float, float]], rtl: bool = True) -> None:
    """A mission of waypoints (north, east [m], altitude above home [m]) through the protocol, as a ground
    station uploads it, ending with a return to launch."""
    from quadsitl.frames import ned_to_geodetic

    items = []
    for north, east, alt in points:
        lat, lon = ned_to_geodetic(north, east, 47.397742, 8.545594)
        items.append(
            (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, round(lat * 1e7), round(lon * 1e7), alt)
        )
    if rtl:
        items.append((M.MAV_FRAME_MISSION, M.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0.0))
    c.conn.mav.mission_count_send(1, 1, len(items), 0)
    while True:
        m = c.wait("MISSION_REQUEST_INT", timeout=5) if "MISSION_ACK" not in c.latest else None
        if m is None:
            break
        frame, cmd, x, y, z = items[m.seq]
        c.conn.mav.mission_item_int_send(1, 1, m.seq, frame, cmd, int(m.seq == 0), 1, 0, 1.0, 0, math.nan, x, y, z, 0)
        if m.seq == len(items) - 1:
            assert c.wait("MISSION_ACK").type == M.MAV_MISSION_ACCEPTED
            break


def test_50k_hostile_datagrams_while_a_mission_flies(flying_vehicle):
    """The mission flies on and completes, landing at home, while hostile datagrams (mission messages among
    them: uploads are refused while it flies) hit every port."""
    ap, plant, ports = flying_vehicle
    c = Client.to(ports["api"])
    try:
        c.connect()
        upload(c, [(15.0, 0.0, 4.0), (15.0, 15.0, 4.0), (0.0, 15.0, 4.0), (0.0, 0.0, 4.0)])
        c.param_set("RTL_RETURN_ALT", 5.0)
        assert c.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED
        assert c.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED
        c.wait("MISSION_CURRENT", lambda m: m.mission_state == 3, timeout=5)  # active
        # In the air: on the ground a stranger's takeoff (22, among the fuzzer's commands) is taken, as PX4 takes it,
        # which pauses the mission, and a clear then empties it (a loaded CI machine got there)
        c.wait("LOCAL_POSITION_NED", lambda m: m.z < -1.0, timeout=30)
        rng = random.Random(int(os.environ.get("QUADSITL_FUZZ_SEED", "20261123")) + 1)
        pool = datagrams(rng, 5000)
        targets = [("127.0.0.1", ports[k]) for k in ("api", "gcs", "plant_listen", "plant_bind")]
        fuzz = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sent = 0
        while sent < 50_000:
            for _ in range(200):
                fuzz.sendto(pool[rng.randrange(len(pool))], targets[sent % len(targets)])
                sent += 1
            c.pump(0.005)
            assert ap.poll() is None and plant.poll() is None
        fuzz.close()
        try:
            reached = c.wait("MISSION_CURRENT", lambda m: m.mission_state == 5, timeout=90)  # complete
            c.wait("HEARTBEAT", lambda m: not m.base_mode & M.MAV_MODE_FLAG_SAFETY_ARMED, timeout=90)  # landed
        except AssertionError as exc:  # say where the vehicle was and what it said
            p, hb = c.latest.get("LOCAL_POSITION_NED"), c.latest.get("HEARTBEAT")
            texts = [t for t in c.texts if "efused" not in t][-15:]
            pos_now = None if p is None else (p.x, p.y, p.z, p.vx, p.vy, p.vz)
            mode = None if hb is None else (hb.custom_mode, hb.base_mode)
            raise AssertionError(f"{exc}\nposition {pos_now}, mode {mode}, {c.latest.get('MISSION_CURRENT')}, "
                                 f"said {texts}") from None  # fmt: skip
        pos = c.wait("LOCAL_POSITION_NED")
    finally:
        c.conn.close()
    assert reached.total == 5 and math.hypot(pos.x, pos.y) < 0.5 and pos.z > -0.1
