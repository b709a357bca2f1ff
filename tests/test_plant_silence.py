"""A plant is lost when it says nothing for PLANT_LOST_AFTER, not when the autopilot's loop was held up elsewhere
(a telemetry put that waited for a stopped subscriber's room) while the plant's datagrams waited in the socket:
under CI's load a circle flight's autopilot once took that for a lost plant, landed, and the flight never ended."""

import select
import socket

from autopilot.plant_link import PLANT_LOST_AFTER, PlantLink


def test_a_plant_whose_datagram_waits_unread_is_not_silent():
    link = PlantLink("127.0.0.1:0", 0.001, 1)
    plant = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    plant.bind(("127.0.0.1", 0))
    try:
        assert not link.silent(1e6)  # no plant locked yet: nothing to lose
        link.admit(plant.getsockname(), 100.0)
        assert not link.silent(100.0 + PLANT_LOST_AFTER)
        assert link.silent(100.0 + PLANT_LOST_AFTER + 0.01)  # nothing said, nothing waiting: lost
        plant.sendto(b"tick", link.sock.getsockname())
        assert select.select([link.sock], [], [], 5.0)[0]
        assert not link.silent(100.0 + 10.0)  # it spoke; the loop had not read it yet
        assert link.sock.recvfrom(64)[0] == b"tick"
        assert link.silent(100.0 + 10.0)
        link.lost = True
        assert not link.silent(100.0 + 10.0)  # said once
    finally:
        plant.close()
        link.sock.close()
