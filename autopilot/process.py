"""The autopilot process (``quadsitl autopilot``, ``python -m autopilot``): a thin shell around the
controller and the commander.

Two UDP sockets: the plant link (answers each ODOMETRY with HIL_ACTUATOR_CONTROLS for the same
``time_usec``) and the ground-station link (MAVLink 2, PX4 conventions; it answers whoever talks to
it). Every control tick it publishes state, reference, actuators and status to Zenoh
(:mod:`quadsitl.telemetry`); publishing drops rather than blocks, so the loop never waits on a subscriber.
"""

from __future__ import annotations

import argparse
import math
import select
import socket
import sys
import time
from collections.abc import Sequence

import zenoh

from autopilot.commander import Commander, CommanderSettings
from autopilot.factory import make_controller
from autopilot.gains import GainError
from quadsitl import telemetry, wire
from quadsitl.cli_util import UsageError, check_range
from quadsitl.config import ConfigError, Preset, load_preset
from quadsitl.frames import euler_to_quaternion, quaternion_to_euler
from quadsitl.mixer import allocate
from quadsitl.process_util import die_with_parent, exit_on_signals, parse_address

mavlink = wire.mavlink
ZERO4 = (0.0, 0.0, 0.0, 0.0)


class Autopilot:
    def __init__(self, preset: Preset, args: argparse.Namespace) -> None:
        self.preset = preset
        self.period = preset.sim.period
        self.controller = make_controller(preset, args.controller)
        self.commander = Commander(CommanderSettings(setpoint_timeout=args.setpoint_timeout))
        self.sysid = args.system_id
        self.compid = wire.AUTOPILOT_COMPONENT_ID
        self.mav = wire.link(self.sysid, self.compid)
        self.plant_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.plant_sock.bind(parse_address("--plant-listen", args.plant_listen))
        self.gcs_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.gcs_sock.bind(parse_address("--gcs-listen", args.gcs_listen))
        self.gcs_peers: dict[tuple[str, int], float] = {}
        self.telemetry_every = max(1, round(1.0 / (args.telemetry_rate * self.period)))
        self.status_every = max(1, round(0.5 / self.period))
        self.was_armed = False
        self.u = ZERO4
        self.forces = ZERO4
        self.last_heartbeat = 0.0
        self.last_state_usec = -1
        act = preset.actuators
        self.f_min, self.f_max, self.d_over_b = act.min_thrust, act.max_thrust, preset.vehicle.d_over_b
        self.session = None
        self.pubs: dict[str, zenoh.Publisher] = {}
        if not args.no_zenoh:
            conf = telemetry.config_from_args(args)
            self.session = zenoh.open(conf)
            for stream in telemetry.STREAMS:
                self.pubs[stream] = self.session.declare_publisher(
                    telemetry.key(args.vehicle, stream),
                    encoding=telemetry.encoding(stream),
                    congestion_control=zenoh.CongestionControl.DROP,
                )

    # ---- the control tick ----------------------------------------------------------------------

    def on_state(self, m: mavlink.MAVLink_odometry_message, sender: tuple[str, int]) -> None:
        if m.time_usec == self.last_state_usec:
            self._answer(m.time_usec, sender)  # a re-sent (free-wheeling) state: same answer
            return
        if self.last_state_usec - 1_000_000 < m.time_usec < self.last_state_usec:
            return  # stale or reordered; a jump back by more than 1 s is a restarted plant
        self.last_state_usec = m.time_usec
        tick = wire.tick_of(m.time_usec, self.period)
        now = tick * self.period
        state = wire.state_from_message(m)
        ref = self.commander.update(tick, now, state)
        if ref is None:
            self.u, self.forces = ZERO4, ZERO4
        else:
            if not self.was_armed:
                self.controller.reset()
            self.u = self.controller.step(state, ref)
            self.forces = allocate(self.u, self.d_over_b, self.f_min, self.f_max)
        self.was_armed = ref is not None
        self._answer(m.time_usec, sender)
        shown = ref if ref is not None else self.commander.hold
        if self.pubs:
            self._publish(tick, now, m, state, shown)
        if self.gcs_peers:
            if tick % self.telemetry_every == 0:
                self._send_telemetry(now, m, state, shown)
            if tick % self.status_every == 0:
                self._send_gcs(mavlink.MAVLink_sys_status_message(0, 0, 0, 0, 65535, -1, -1, 0, 0, 0, 0, 0, 0))
        for severity, text in self.commander.messages:
            self._send_gcs(mavlink.MAVLink_statustext_message(severity, text.encode()[:50]))
        self.commander.messages.clear()

    def _answer(self, time_usec: int, sender: tuple[str, int]) -> None:
        msg = wire.actuator_message(time_usec, self.forces, self.f_max, self.commander.armed)
        self.plant_sock.sendto(msg.pack(self.mav), sender)

    def _publish(self, tick, now, m, state, ref) -> None:
        s = telemetry.STREAMS
        c = self.commander
        self.pubs["state"].put(s["state"].pack(
            tick, now, state.x, state.y, state.z, state.vx, state.vy, state.vz, state.roll, state.pitch,
            state.yaw, m.rollspeed, m.pitchspeed, m.yawspeed))  # fmt: skip
        self.pubs["setpoint"].put(s["setpoint"].pack(tick, now, *ref))
        self.pubs["actuators"].put(s["actuators"].pack(tick, now, *self.u, *self.forces))
        self.pubs["status"].put(s["status"].pack(tick, now, c.armed, c.mode, c.failsafe, c.offboard_tick))

    # ---- the ground-station link ---------------------------------------------------------------

    def _send_gcs(self, msg) -> None:
        buf = msg.pack(self.mav)
        for peer in list(self.gcs_peers):
            try:
                self.gcs_sock.sendto(buf, peer)
            except OSError:
                self.gcs_peers.pop(peer, None)

    def _send_telemetry(self, now, m, state, ref) -> None:
        ms = int(now * 1000) & 0xFFFFFFFF
        self._send_gcs(mavlink.MAVLink_attitude_message(
            ms, state.roll, state.pitch, state.yaw, m.rollspeed, m.pitchspeed, m.yawspeed))  # fmt: skip
        self._send_gcs(mavlink.MAVLink_local_position_ned_message(ms, m.x, m.y, m.z, m.vx, m.vy, m.vz))
        q = euler_to_quaternion(ref.roll, ref.pitch, ref.yaw)
        thrust = max(0.0, min(1.0, self.u[0] / (4.0 * self.f_max)))
        self._send_gcs(mavlink.MAVLink_attitude_target_message(ms, 7, q, 0.0, 0.0, 0.0, thrust))

    def heartbeat(self) -> None:
        c = self.commander
        base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (mavlink.MAV_MODE_FLAG_SAFETY_ARMED if c.armed else 0)
        status = mavlink.MAV_STATE_ACTIVE if c.armed else mavlink.MAV_STATE_STANDBY
        hb = mavlink.MAVLink_heartbeat_message
        self._send_gcs(
            hb(mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_PX4, base, c.mode.px4_custom_mode, status, 3)
        )

    def on_gcs(self, m, sender: tuple[str, int]) -> None:
        new_peer = sender not in self.gcs_peers
        self.gcs_peers[sender] = time.monotonic()
        if new_peer:
            self.heartbeat()
        mid = m.get_msgId()
        if not hasattr(m, "target_system") or not self._for_me(m.target_system, m.target_component):
            return
        if mid == mavlink.MAVLINK_MSG_ID_COMMAND_LONG:
            self._command(m)
        elif mid == mavlink.MAVLINK_MSG_ID_SET_ATTITUDE_TARGET:
            # type_mask 128: ignore attitude. The thrust field is always ignored: the altitude loop makes it.
            q_ok = all(math.isfinite(x) for x in m.q) and abs(sum(x * x for x in m.q) - 1.0) < 0.1
            if not m.type_mask & 128 and q_ok:
                self.commander.on_attitude_setpoint(*quaternion_to_euler(*m.q))
        elif mid == mavlink.MAVLINK_MSG_ID_SET_POSITION_TARGET_LOCAL_NED:
            if m.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED:
                return
            z_ignored = bool(m.type_mask & 4)  # z is down: altitude = −z
            if z_ignored or math.isfinite(m.z):
                self.commander.on_altitude_setpoint(None if z_ignored else -m.z)

    def _for_me(self, system: int, component: int) -> bool:
        return system in (0, self.sysid) and component in (0, self.compid)

    def _command(self, m) -> None:
        c = self.commander
        result, reason = mavlink.MAV_RESULT_ACCEPTED, ""
        if m.command == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            if m.param1 == 1.0:
                ok, reason = c.arm()
                result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED
            elif m.param1 == 0.0:
                c.disarm()
            else:
                result = mavlink.MAV_RESULT_DENIED
                reason = f"Arm/disarm: param1 {m.param1:g} is neither 0 nor 1"
        elif m.command == mavlink.MAV_CMD_DO_SET_MODE:
            mode = wire.Mode.from_px4((int(m.param2) << 16) | (int(m.param3) << 24))
            if mode is None:
                result = mavlink.MAV_RESULT_UNSUPPORTED
            else:
                ok, reason = c.set_mode(mode)
                result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED
        elif m.command == mavlink.MAV_CMD_NAV_LAND:
            ok, reason = c.set_mode(wire.Mode.LAND)
            result = mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED
        else:
            result = mavlink.MAV_RESULT_UNSUPPORTED
        self._send_gcs(
            mavlink.MAVLink_command_ack_message(m.command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent())
        )
        if reason:
            self._send_gcs(mavlink.MAVLink_statustext_message(mavlink.MAV_SEVERITY_WARNING, reason.encode()[:50]))

    # ---- the loop ------------------------------------------------------------------------------

    def run(self) -> None:
        socks = [self.plant_sock, self.gcs_sock]
        odometry = mavlink.MAVLINK_MSG_ID_ODOMETRY
        while True:
            ready, _, _ = select.select(socks, [], [], 0.1)
            for sock in ready:
                data, sender = sock.recvfrom(65535)
                try:
                    msgs = self.mav.parse_buffer(data) or []
                except mavlink.MAVError:
                    continue
                if sock is self.plant_sock:
                    for m in msgs:
                        if m.get_msgId() == odometry:
                            self.on_state(m, sender)
                else:
                    for m in msgs:
                        self.on_gcs(m, sender)
            wall = time.monotonic()
            if wall - self.last_heartbeat >= 1.0:
                self.last_heartbeat = wall
                self.heartbeat()

    def close(self) -> None:
        for pub in self.pubs.values():
            pub.undeclare()
        if self.session is not None:
            self.session.close()
        self.plant_sock.close()
        self.gcs_sock.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="quadsitl autopilot",
        description="The autopilot: discrete backstepping (or PD) control loop, MAVLink to the plant and to "
        "ground stations, telemetry to Zenoh.",
        epilog="examples:\n  quadsitl autopilot --preset paper\n"
        "  quadsitl autopilot --preset x500 --controller pd --zenoh-listen tcp/127.0.0.1:7447",
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--preset", default="paper", help="preset name or TOML path (default: paper)")
    p.add_argument("--controller", choices=("backstepping", "pd"), help="default: the preset's")
    p.add_argument(
        "--plant-listen",
        default="127.0.0.1:14560",
        metavar="HOST:PORT",
        help="UDP address for the plant link (default: 127.0.0.1:14560)",
    )
    p.add_argument(
        "--gcs-listen",
        default="127.0.0.1:14580",
        metavar="HOST:PORT",
        help="UDP address for ground stations (default: 127.0.0.1:14580)",
    )
    p.add_argument("--system-id", type=int, default=1, help="MAVLink system id (default: 1)")
    p.add_argument(
        "--telemetry-rate",
        type=float,
        default=50.0,
        metavar="HZ",
        help="ATTITUDE, LOCAL_POSITION_NED, ATTITUDE_TARGET rate in simulated time (default: 50)",
    )
    p.add_argument(
        "--setpoint-timeout",
        type=float,
        default=1.0,
        metavar="S",
        help="offboard setpoint loss failsafe, simulated seconds (default: 1)",
    )
    telemetry.add_zenoh_arguments(p)
    p.add_argument("--no-zenoh", action="store_true", help="do not publish telemetry to Zenoh")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    die_with_parent()
    exit_on_signals()
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        preset = load_preset(args.preset)
        check_range("--telemetry-rate", args.telemetry_rate, 0.0, 1.0 / preset.sim.period)
        check_range("--setpoint-timeout", args.setpoint_timeout, 0.0, 3600.0)
        if not 1 <= args.system_id <= 255:
            raise UsageError(f"--system-id {args.system_id}: expected an integer in 1..255")
        ap = Autopilot(preset, args)
    except (UsageError, ConfigError, GainError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(
            f"{parser.prog}: error: cannot bind --plant-listen {args.plant_listen} / --gcs-listen "
            f"{args.gcs_listen}: {exc.strerror}",
            file=sys.stderr,
        )
        return 2
    try:
        ap.run()
    except KeyboardInterrupt:
        pass
    finally:
        ap.close()
    return 0
