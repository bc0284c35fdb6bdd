"""``manage.py mavsim NAME``: a simulated copter from the fleet's database, in a process of
its own, answering a plain pymavlink ground station."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from django.core.management import CommandError, call_command
from pymavlink import mavutil

from fleet.mavlink.wire import mavlink
from tests.factories import VehicleFactory
from tests.fleet.mavlink.conftest import free_udp_port
from tests.live import database_url

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.slow
@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_mavsim_flies_a_vehicle_of_the_fleet(tmp_path: Path) -> None:
    port = free_udp_port()
    VehicleFactory(
        name="Heli MAV",
        depot_lat=48.1135,
        depot_lng=12.86,
        max_speed_mps=12.0,
        climb_rate_mps=2.5,
        battery_s=300.0,
        driver="mavlink",
        driver_url=f"udpout:127.0.0.1:{port}",  # mavsim listens on the other end
    )
    log = tmp_path / "mavsim.log"
    with log.open("wb") as out:
        process = subprocess.Popen(
            [sys.executable, "manage.py", "mavsim", "Heli MAV", "--speed", "10"],
            cwd=ROOT,
            env={
                **os.environ,
                "DATABASE_URL": database_url(),
                "CPCC_VAR_DIR": str(tmp_path / "var"),
                "CPCC_LOG_LEVEL": "INFO",
            },
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    gcs = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)
    try:
        # Django starts in a second or two: say hello until the copter answers.
        deadline = time.monotonic() + 60
        beat = None
        while beat is None:
            assert process.poll() is None, log.read_text()
            assert time.monotonic() < deadline, f"no heartbeat from mavsim\n{log.read_text()}"
            gcs.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            beat = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.2)
        assert beat.type == mavlink.MAV_TYPE_QUADROTOR
        assert beat.autopilot == mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA

        # Its speeds and home are the vehicle's.
        gcs.mav.param_request_read_send(1, 1, b"WPNAV_SPEED_UP", -1)
        climb = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=5)
        assert climb is not None and climb.param_value == 250.0
        gcs.mav.command_long_send(
            1, 1, mavlink.MAV_CMD_REQUEST_MESSAGE, 0, mavlink.MAVLINK_MSG_ID_HOME_POSITION,
            0, 0, 0, 0, 0, 0,
        )  # fmt: skip
        home = gcs.recv_match(type="HOME_POSITION", blocking=True, timeout=5)
        assert home is not None and (home.latitude, home.longitude) == (481135000, 128600000)

        os.killpg(process.pid, signal.SIGTERM)
        assert process.wait(timeout=15) == 0
        assert "mavsim Heli MAV: ardupilot copter on udpin:127.0.0.1:" in log.read_text()
    finally:
        gcs.close()
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


@pytest.mark.django_db
def test_mavsim_needs_a_vehicle_and_a_connection() -> None:
    VehicleFactory(name="Heli One", driver_url="")
    with pytest.raises(CommandError, match=r"no vehicle named 'Heli Two' \(vehicles: Heli One\)"):
        call_command("mavsim", "Heli Two")
    with pytest.raises(CommandError, match="Heli One has no driver_url: give --connection"):
        call_command("mavsim", "Heli One")
    with pytest.raises(CommandError, match="unknown MAVLink connection"):
        call_command("mavsim", "Heli One", "--connection", "bluetooth:heli")
