"""A ground-station link whose sends the OS refuses: counted, said once per destination and error on stderr,
never raised (a flight controller does not stop because a ground station is unreachable)."""

import socket

from autopilot.ground_link import GcsLink
from autopilot.streams import MessageStreams


def test_refused_sends_are_counted_and_said_once_per_destination_and_error(capsys):
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as listener:  # fmt: skip
        sock.bind(("127.0.0.1", 0))
        listener.bind(("127.0.0.1", 0))
        # A loopback-bound socket cannot reach another host (EINVAL): the mistake `up` once made with --gcs-remote.
        link = GcsLink("gcs", sock, ("10.255.255.1", 14550), MessageStreams(0.001, 1.0), "autopilot v2")
        link.peers[listener.getsockname()] = 0.0  # a learned peer that works
        for _ in range(3):
            link.send(b"x")
        assert link.send_errors == 3
        assert listener.recv(16) == b"x"  # the reachable peer still gets every datagram
        lines = [line for line in capsys.readouterr().err.splitlines() if "cannot send" in line]
        port = sock.getsockname()[1]
        assert lines == [f"autopilot v2: gcs link: cannot send to 10.255.255.1:14550 from 127.0.0.1:{port}: Invalid "
                         "argument (said once for this destination and error)"]  # fmt: skip
        link.peers[("127.0.0.1", 0)] = 0.0  # a learned peer the OS refuses (port 0): dropped, said once
        link.send(b"y")
        assert ("127.0.0.1", 0) not in link.peers and link.send_errors == 5
        assert capsys.readouterr().err.count("cannot send to 127.0.0.1:0") == 1
