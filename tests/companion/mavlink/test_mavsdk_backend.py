"""The MAVSDK backend's own parts: messages from MAVSDK's JSON into pymavlink objects, URLs, MAVSDK's results as
our errors, and `fly --backend mavsdk` on the built-in simulator (the real autopilots: tests/px4,
tests/conformance/test_mavsdk_ground.py)."""

from __future__ import annotations

import asyncio
import json
import math
import socket
from pathlib import Path

import pytest
from mavsdk.plugins.mission_raw import MissionRawError, MissionRawResult
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.cli import main
from companion.mavlink.errors import LinkError, MissionTimeout, MissionUploadError
from companion.mavlink.mavsdk_backend import MESSAGES, from_message, mavsdk_url, to_message, upload_error

ROOT = Path(__file__).resolve().parents[3]

SAMPLES = {
    "HEARTBEAT": mavlink.MAVLink_heartbeat_message(2, 12, 29, 50593792, 3, 3),
    "STATUSTEXT": mavlink.MAVLink_statustext_message(2, b"Arm: AUTO mode not armable", 7, 1),
    "ADSB_VEHICLE": mavlink.MAVLink_adsb_vehicle_message(0xC0FFEE, 473977000, 85456000, 0, 500000, 9000, 1500, -200,
                                                         b"RESCUE1", 14, 1, 0x1FF, 7000),
    "MISSION_CURRENT": mavlink.MAVLink_mission_current_message(3, 15, 2, 3),
    "GLOBAL_POSITION_INT": mavlink.MAVLink_global_position_int_message(1000, 473977000, 85456000, 500000, 12000,
                                                                       10, -20, 30, 9000),
    "COMMAND_ACK": mavlink.MAVLink_command_ack_message(400, 4, 0, 0, 1, 195),
    "EKF_STATUS_REPORT": mavlink.MAVLink_ekf_status_report_message(0x33F, 0.1, 0.2, 0.3, 0.4, 0.5, math.nan),
}


@pytest.mark.parametrize("name", sorted(SAMPLES))
def test_a_message_from_mavsdk_json_is_the_pymavlink_message(name: str) -> None:
    """What MAVSDK hands over (the fields as JSON, NaN as null) becomes the same pymavlink message, with the
    sender's ids, so the layers above read it as from our own link."""
    sent = SAMPLES[name]
    fields = {"message_id": sent.get_msgId(), "message_name": name, **from_message(sent)}
    text = json.dumps(fields).replace("NaN", "null")
    got = to_message(name, 1, 156, text)
    assert got.get_type() == name and (got.get_srcSystem(), got.get_srcComponent()) == (1, 156)
    for field in sent.get_fieldnames():
        a, b = getattr(sent, field), getattr(got, field)
        assert a == b or (isinstance(a, float) and math.isnan(a) and math.isnan(b)), (field, a, b)


def test_every_message_the_companion_reads_comes_through() -> None:
    """Each name the backend subscribes to is a message pymavlink knows; the ones the layers wait for are in."""
    for name in MESSAGES:
        assert getattr(mavlink, f"MAVLINK_MSG_ID_{name}") in mavlink.mavlink_map
    assert {"HEARTBEAT", "MISSION_CURRENT", "MISSION_ITEM_REACHED", "GLOBAL_POSITION_INT", "STATUSTEXT",
            "COMMAND_ACK", "ADSB_VEHICLE", "SYS_STATUS", "GPS_RAW_INT"} <= set(MESSAGES)


@pytest.mark.parametrize(("ours", "theirs"), [
    ("udpin:127.0.0.1:14540", "udpin://127.0.0.1:14540"), ("udp:0.0.0.0:14550", "udpin://0.0.0.0:14550"),
    ("udpout:127.0.0.1:14580", "udpout://127.0.0.1:14580"), ("tcp:127.0.0.1:5762", "tcpout://127.0.0.1:5762"),
    ("/dev/ttyACM0,921600", "serial:///dev/ttyACM0:921600"), ("udpin://0.0.0.0:14540", "udpin://0.0.0.0:14540"),
])
def test_connection_strings_as_mavsdk_writes_them(ours: str, theirs: str) -> None:
    assert mavsdk_url(ours) == theirs


def test_a_connection_mavsdk_cannot_use_says_so() -> None:
    with pytest.raises(LinkError, match="cannot use connection 'tcpin:1.2.3.4:5' with MAVSDK"):
        mavsdk_url("tcpin:1.2.3.4:5")


def test_mavsdk_results_become_our_errors() -> None:
    """A refusal stays a refusal (not retried), MAVSDK's ERROR may be the autopilot's transfer trouble (retried,
    as PX4's MAV_MISSION_ERROR on our link), a timeout or cancelled transfer is transient."""
    def err(result: MissionRawResult) -> Exception:
        return upload_error(MissionRawError(result, "upload_mission()"), "upload")

    refused = err(MissionRawResult.UNSUPPORTED)
    assert isinstance(refused, MissionUploadError) and refused.refused
    assert refused.result == mavlink.MAV_MISSION_UNSUPPORTED
    assert err(MissionRawResult.TOO_MANY_MISSION_ITEMS).result == mavlink.MAV_MISSION_NO_SPACE
    fault = err(MissionRawResult.ERROR)
    assert isinstance(fault, MissionUploadError) and not fault.refused
    for transient in (MissionRawResult.TIMEOUT, MissionRawResult.TRANSFER_CANCELLED, MissionRawResult.BUSY):
        assert isinstance(err(transient), MissionTimeout)


def test_fly_with_mavsdk_refuses_signing_in_one_line(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    key = tmp_path / "key"
    key.write_bytes(bytes(range(32)))
    key.chmod(0o600)
    code = main(["fly", str(ROOT / "sitl_scenarios" / "rescue_static.toml"), "--sim", "--backend", "mavsdk",
                 "--signing-key", str(key), "--report", str(tmp_path / "r"), "-q"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code != 0 and len(err) == 1 and "MAVSDK" in err[0] and "signing" in err[0], err


def test_fly_and_replan_through_mavsdk_on_the_simulator(tmp_path: Path) -> None:
    """`fuseplan fly rescue_dynamic.toml --sim --backend mavsdk`: uploaded (mission and fence) and verified
    through MAVSDK, started, the intruder's conflict replanned in flight through MAVSDK (a new mission uploaded,
    verified and made current, or the vehicle held until it had passed), flown to the goal clear of it; the
    report says which backend flew it."""
    report = tmp_path / "report"
    code = main(["fly", str(ROOT / "sitl_scenarios" / "rescue_dynamic.toml"), "--sim", "--speedup", "20",
                 "--backend", "mavsdk", "--report", str(report), "-q"])
    flight = json.loads((report / "flight.json").read_text())
    events = [json.loads(line)["event"] for line in (report / "events.jsonl").read_text().splitlines()]
    assert code == 0 and flight["completed"] is True, flight.get("reason")
    assert flight["backend"] == "mavsdk" and flight["fence_items"] > 0
    assert flight["tlog"] is None and not (report / "flight.tlog").exists()  # MAVSDK gives us no bytes to log
    assert events.index("upload_verified") < events.index("armed") < events.index("mission_start")
    assert len(flight["items_reached"]) >= 3
    assert flight["replan_attempts"] >= 1
    assert min(flight["min_separation_m"].values()) >= flight["d_coll_m"], flight["min_separation_m"]
    if flight["replans"]:  # a new mission went live through MAVSDK
        assert events.index("conflict") < events.index("replan_verified") < events.index("replanned")
    else:  # no safe detour in time: held until the intruder had passed
        assert "hold" in events and "resume" in events


@pytest.mark.asyncio
async def test_no_autopilot_on_the_connection_is_a_link_error_and_nothing_is_left_running() -> None:
    """MAVSDK finds no autopilot on a port nobody answers: a LinkError naming the URL, MAVSDK destroyed (the
    leak check of this package sees no thread, task or socket left)."""
    from companion.mavlink.mavsdk_backend import MavsdkLink

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    link = MavsdkLink(f"udpout:127.0.0.1:{port}", open_timeout=0.5)
    with pytest.raises(LinkError, match=f"MAVSDK found no autopilot on udpout:127.0.0.1:{port}"):
        await link.open()
    assert link.sdk is None and not link.connected
    await asyncio.get_running_loop().shutdown_default_executor()  # MAVSDK's blocking calls ran there
