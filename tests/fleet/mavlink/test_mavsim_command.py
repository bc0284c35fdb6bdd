"""``manage.py mavsim NAME``: a simulated copter from the fleet's database, in a process of
its own, answering a plain pymavlink ground station; by default it carries its payload (the
companion computer and the camera), reads the seeded field (``--field-seed``) and says where
its images are served."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import closing
from pathlib import Path
from typing import Any

import pytest
from django.core.management import CommandError, call_command
from pymavlink import mavutil

from fleet.geo import Position
from fleet.mavlink.wire import mavlink
from fleet.simulation import SensorField
from tests.factories import VehicleFactory
from tests.fleet.mavlink.conftest import free_udp_port
from tests.fleet.mavlink.test_mavsim_sensors import sdc
from tests.live import database_url

ROOT = Path(__file__).resolve().parents[3]
SEED = 11
DEPOT = Position(48.1135, 12.86, 0.0)


@contextlib.contextmanager
def mavsim(name: str, *args: str, tmp_path: Path) -> Iterator[tuple[subprocess.Popen[bytes], Path]]:
    """``manage.py mavsim NAME ARGS`` in a process of its own (and its log), killed at the end
    if the test did not stop it."""
    log = tmp_path / "mavsim.log"
    with log.open("wb") as out:
        process = subprocess.Popen(
            [sys.executable, "manage.py", "mavsim", name, *args],
            cwd=ROOT,
            env={
                **os.environ,
                "DATABASE_URL": database_url(),
                "CPCC_VAR_DIR": str(tmp_path / "var"),
            },
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
    try:
        yield process, log
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)
            process.wait()


def receive(gcs: Any, kind: str, condition: Any, deadline: float) -> Any:
    """The next message of a kind that ``condition`` accepts, saying hello meanwhile."""
    while time.monotonic() < deadline:
        gcs.mav.heartbeat_send(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        msg = gcs.recv_match(type=kind, blocking=True, timeout=0.2)
        if msg is not None and condition(msg):
            return msg
    raise AssertionError(f"no {kind}")


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
    with (
        mavsim("Heli MAV", "--speed", "10", tmp_path=tmp_path) as (process, log),
        closing(mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)) as gcs,
    ):
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

        # Its flight is in its log at the default level (mode changes, take-off, landing).
        gcs.mav.set_mode_send(1, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
        deadline = time.monotonic() + 10
        while "mavsim Heli MAV: mode STABILIZE -> GUIDED" not in log.read_text():
            assert time.monotonic() < deadline, log.read_text()
            time.sleep(0.05)

        os.killpg(process.pid, signal.SIGTERM)
        assert process.wait(timeout=15) == 0
        assert "mavsim Heli MAV: ardupilot copter on udpin:127.0.0.1:" in log.read_text()


@pytest.mark.django_db
def test_mavsim_needs_a_vehicle_and_a_connection() -> None:
    VehicleFactory(name="Heli One", driver_url="")
    with pytest.raises(CommandError, match=r"no vehicle named 'Heli Two' \(vehicles: Heli One\)"):
        call_command("mavsim", "Heli Two")
    with pytest.raises(CommandError, match="Heli One has no driver_url: give --connection"):
        call_command("mavsim", "Heli One")
    with pytest.raises(CommandError, match="unknown MAVLink connection"):
        call_command("mavsim", "Heli One", "--connection", "bluetooth:heli")


@pytest.mark.slow
@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_mavsim_command_flies_with_its_payload(tmp_path: Path) -> None:
    port = free_udp_port()
    VehicleFactory(
        name="Heli Payload",
        depot_lat=DEPOT.lat,
        depot_lng=DEPOT.lng,
        driver="mavlink",
        driver_url=f"udpout:127.0.0.1:{port}",
    )
    with (
        mavsim("Heli Payload", "--field-seed", str(SEED), tmp_path=tmp_path) as (process, log),
        closing(mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=255)) as gcs,
    ):
        # Django starts in a second or two.
        deadline = time.monotonic() + 60
        pressure = receive(gcs, "SCALED_PRESSURE", lambda m: True, deadline)
        expected = SensorField(SEED).sample(sdc("pressure"), DEPOT, 0.0)["value"]
        assert abs(pressure.press_abs - expected) < 0.5  # the seeded world, not seed 0's
        companion = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER
        co2 = receive(
            gcs,
            "NAMED_VALUE_FLOAT",
            lambda m: m.get_srcComponent() == companion and m.name == "CO2",
            time.monotonic() + 10,
        )
        assert co2.value > 350
        receive(
            gcs,
            "HEARTBEAT",
            lambda m: m.get_srcComponent() == mavlink.MAV_COMP_ID_CAMERA,
            time.monotonic() + 10,
        )
        # The command says where the images are; the server answers there.
        line = next(x for x in log.read_text().splitlines() if "camera images on" in x)
        url = line.split("camera images on ")[1]
        assert url.startswith("http://127.0.0.1:")
        with pytest.raises(urllib.error.HTTPError) as none_yet:
            urllib.request.urlopen(url + "0.png", timeout=5)
        assert none_yet.value.code == 404

        os.killpg(process.pid, signal.SIGTERM)
        assert process.wait(timeout=15) == 0
