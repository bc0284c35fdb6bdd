"""Readings from the vehicle's own sensors over MAVLink (issue 24): ``MavlinkDriver.
read_sensor`` against MavSim, whose autopilot, companion computer and camera publish what they
measure the way ArduPilot and PX4 do. MavSim's world is overridden here with values the
platform's simulated field never gives, so a reading provably comes from the vehicle."""

from __future__ import annotations

import io
from collections.abc import Callable, Iterator
from typing import Any

import PIL.Image
import pytest

from fleet.driving import SensorFailure, SensorRead
from fleet.geo import distance_m
from fleet.mavlink import MavlinkDriver, MavSim
from fleet.mavlink.sim.companion import FieldSensors
from tests.fleet.mavlink.conftest import DEPOT, SPEC, sim_clock, wait_until

SPEED = 20.0
# What MavSim's sensors measure in these tests, by SDC quantity.
MEASURED = {"co2": 1234.5, "nox": 42.25, "temperature": 21.5, "pressure": 1000.25}


@pytest.fixture(autouse=True)
def _measured(monkeypatch) -> None:
    monkeypatch.setattr(
        FieldSensors, "value", lambda self, quantity, position, time_s: MEASURED[quantity]
    )


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED, payload=True)


@pytest.fixture
def driver(port: int, sim: MavSim) -> Iterator[MavlinkDriver]:
    driver = MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=SPEC,
        depot=DEPOT,
        clock=sim_clock(SPEED),
        command_timeout_s=0.5,
        link_timeout_s=1.0,
        name="Heli One",
    )
    driver.connect(timeout_s=5.0)
    yield driver
    driver.close()


def read(sensor: str, kind: str, source: str, **more: Any) -> SensorRead:
    return SensorRead(sensor=sensor, kind=kind, source=source, timeout_s=3.0, **more)


def test_scalar_readings_come_from_the_autopilot_and_the_companion(driver: MavlinkDriver) -> None:
    co2 = driver.read_sensor(read("CO2", "scalar", "named_value", name="CO2"))
    assert co2.fields == {"value": 1234.5}
    assert driver.read_sensor(read("NOx", "scalar", "named_value", name="NOx")).fields == {
        "value": 42.25
    }
    thermometer = read("Thermometer", "scalar", "telemetry", params={"quantity": "temperature"})
    assert driver.read_sensor(thermometer).fields == {"value": 21.5}
    barometer = read("Barometer", "scalar", "telemetry", params={"quantity": "pressure"})
    assert driver.read_sensor(barometer).fields == {"value": 1000.25}
    # Each carries the vehicle's time and where it was.
    assert distance_m(co2.position, DEPOT) < 1.0
    assert co2.epoch_ms > 1_700_000_000_000


def test_gps_and_altitude_from_the_autopilots_position(driver: MavlinkDriver) -> None:
    gps = driver.read_sensor(read("GPS", "gps", "telemetry"))
    assert abs(gps.fields["lat"] - DEPOT.lat) < 1e-5 and abs(gps.fields["lng"] - DEPOT.lng) < 1e-5
    assert gps.fields["alt"] == pytest.approx(DEPOT.alt, abs=0.5)
    altimeter = read("Altimeter", "scalar", "telemetry", params={"quantity": "altitude"})
    assert driver.read_sensor(altimeter).fields["value"] == pytest.approx(DEPOT.alt, abs=0.5)


def test_a_picture_through_the_camera_protocol(driver: MavlinkDriver) -> None:
    picture = driver.read_sensor(read("Camera 640x480", "camera", "camera"))
    assert picture.fields == {"width": 640, "height": 480, "format": "png"}
    assert picture.image is not None
    with PIL.Image.open(io.BytesIO(picture.image)) as image:
        assert (image.format, image.size) == ("PNG", (640, 480))
    assert distance_m(picture.position, DEPOT) < 1.0


def test_a_reading_that_does_not_come_fails_with_the_reason(
    driver: MavlinkDriver, sim: MavSim
) -> None:
    radon = read("Radon", "scalar", "named_value", name="RADON")
    with pytest.raises(SensorFailure) as failed:
        driver.read_sensor(SensorRead(**{**radon.__dict__, "timeout_s": 0.5}))
    assert failed.value.reason == "no reading within 0.5 s"
    assert "NAMED_VALUE_FLOAT 'RADON'" in str(failed.value)  # the operator's log says what
    assert "127.0.0.1" not in failed.value.reason
    sim.cut_link()
    wait_until(lambda: not driver.link_ok, timeout=5.0, what="the link to be lost")
    with pytest.raises(SensorFailure, match="the vehicle's link is down"):
        driver.read_sensor(read("CO2", "scalar", "named_value", name="CO2"))
