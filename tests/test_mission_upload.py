"""The ground station's side of a mission upload alone (groundstation.mission_upload, pure): what it sends from what
the vehicle asked and when, and how it ends. The whole protocol against the autopilot: tests/test_mission_transfer.py,
tests/test_mission_flight.py."""

from __future__ import annotations

from groundstation.mission_upload import UPLOAD_RETRY, UPLOAD_TIMEOUT, MissionUpload, UploadStep, ack_name
from quadsitl.wire import mavlink


def test_the_count_goes_first_and_again_while_the_vehicle_asks_for_nothing():
    upload = MissionUpload(3, start=100.0)
    assert upload.step(100.0, [], None) == UploadStep([], True, False, None)  # at once
    assert upload.step(100.0 + UPLOAD_RETRY / 2, [], None) == UploadStep([], False, False, None)
    assert upload.step(100.0 + UPLOAD_RETRY * 1.01, [], None).count  # no answer: again


def test_the_items_asked_for_go_in_order_and_a_vehicle_that_asks_defers_the_count():
    upload = MissionUpload(3, start=100.0)
    upload.step(100.0, [], None)
    assert upload.step(100.5, [0, 7, 1, -1, 1], None) == UploadStep([0, 1, 1], False, False, None)  # re-requests too
    assert not upload.step(100.5 + UPLOAD_RETRY * 0.99, [], None).count  # counted from the last request
    assert upload.step(100.5 + UPLOAD_RETRY * 1.01, [], None).count


def test_the_upload_ends_at_the_vehicles_ack_or_gives_up():
    upload = MissionUpload(2, start=0.0)
    assert upload.step(1.0, [1], mavlink.MAV_MISSION_ACCEPTED) == UploadStep([1], False, True, None)
    refused = MissionUpload(2, start=0.0).step(1.0, [], mavlink.MAV_MISSION_UNSUPPORTED)
    assert refused == UploadStep([], False, False, "the vehicle refused the mission: MISSION_ACK "
                                 "MAV_MISSION_UNSUPPORTED (3)")  # fmt: skip
    late = MissionUpload(2, start=0.0).step(UPLOAD_TIMEOUT + 0.1, [], None)
    assert late.error == f"the mission upload did not complete within {UPLOAD_TIMEOUT:g} s" and not late.done


def test_a_result_is_named_with_its_number():
    assert ack_name(mavlink.MAV_MISSION_ACCEPTED) == "MAV_MISSION_ACCEPTED (0)"
    assert ack_name(250) == "unknown (250)"
