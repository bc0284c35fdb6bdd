"""An RV's sensor sources (issue 24): where each sensor's readings come from, checked when a
provider configures them, and a sensor on the vehicle's own computer (the ``mhz19`` plug-in,
a CO2 sensor on a serial line, here on a pty) serving a VV's task end to end."""

from __future__ import annotations

import os
import threading
from collections.abc import Iterator

import pytest
from django.core.exceptions import ValidationError

from fleet.driving import SensorFailure
from fleet.models import Driver
from fleet.plugins import PluginError, plugin_class
from fleet.plugins.mhz19 import MHZ19, READ_CO2, checksum
from fleet.sources import NAMED_VALUE, PLUGIN, TELEMETRY, SensorSource, SourceError, parse_sources
from missions.models import TaskStatus, VVStatus
from tests.factories import VehicleFactory
from vvm_worker.services import vehicle_update, vv_submit

CATALOG = {
    "CO2": {"name": "CO2", "kind": "scalar", "params": {"quantity": "co2"}},
    "Barometer": {"name": "Barometer", "kind": "scalar", "params": {"quantity": "pressure"}},
    "GPS": {"name": "GPS", "kind": "gps", "params": {}},
    "Camera 640x480": {"name": "Camera 640x480", "kind": "camera", "params": {}},
}

ONE_TASK = """
var co2 = VV.sensor.get('CO2');
var d = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                         tolerance: 2, sensors: [co2]});
VV.storage.store('co2', d[0]);
"""

# The same task, with its failure caught by the program.
CATCHING = """
var co2 = VV.sensor.get('CO2');
try {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),
                   tolerance: 2, sensors: [co2]});
} catch (e) {
  VV.storage.store('error', e.name + ': ' + e.message);
}
"""


def test_sources_a_mavlink_vehicle_can_have() -> None:
    parsed = parse_sources(
        {
            "CO2": {"source": "named_value", "name": "CO2_PPM", "timeout_s": 5},
            "Barometer": {"source": "telemetry"},
            "GPS": {"source": "telemetry"},
        },
        catalog=CATALOG,
        mavlink=True,
    )
    assert parsed == {
        "CO2": SensorSource(NAMED_VALUE, name="CO2_PPM", timeout_s=5.0),
        "Barometer": SensorSource(TELEMETRY),
        "GPS": SensorSource(TELEMETRY),
    }
    # The name of a named value defaults to the SDC entry's (at most 10 characters).
    assert parse_sources({"CO2": {"source": "named_value"}}, catalog=CATALOG, mavlink=True) == {
        "CO2": SensorSource(NAMED_VALUE, name="CO2")
    }


@pytest.mark.parametrize(
    ("sources", "mavlink", "error"),
    [
        ([], True, "must be an object mapping SDC entry names to sources, not list"),
        ({"Radar": {"source": "field"}}, True, "sensor 'Radar': no SDC entry of that name"),
        ({"CO2": "field"}, True, "sensor 'CO2': expected an object such as"),
        ({"CO2": {"source": "radio"}}, True, "sensor 'CO2': unknown source 'radio' (sources: "),
        ({"CO2": {"source": "telemetry"}}, True, "the autopilot's telemetry has no co2"),
        ({"CO2": {"source": "named_value"}}, False, "named_value needs a vehicle that speaks"),
        ({"GPS": {"source": "named_value"}}, True, "a named value is a number: not for a gps"),
        ({"CO2": {"source": "named_value", "name": "CARBON_DIOXIDE"}}, True, "1 to 10 char"),
        ({"CO2": {"source": "field", "timeout_s": 1}}, True, "field takes no timeout_s"),
        ({"CO2": {"source": "named_value", "timeout_s": 0}}, True, "timeout_s must be more than"),
        ({"CO2": {"source": "named_value", "timeout_s": "2"}}, True, "must be a number of sec"),
        ({"CO2": {"source": "plugin", "plugin": "geiger"}}, False, "no sensor plug-in named "),
        ({"CO2": {"source": "plugin", "plugin": "mhz19"}}, False, "mhz19 needs port"),
        (
            {"GPS": {"source": "plugin", "plugin": "mhz19", "options": {"port": "/dev/x"}}},
            False,
            "plug-in 'mhz19' reads scalar sensors, not gps ones",
        ),
    ],
)
def test_a_source_that_cannot_work_is_refused_with_the_reason(sources, mavlink, error) -> None:
    with pytest.raises(SourceError) as refused:
        parse_sources(sources, catalog=CATALOG, mavlink=mavlink)
    assert error in str(refused.value)


@pytest.mark.django_db
def test_the_vehicle_api_and_admin_refuse_a_bad_source_naming_the_field(vvm_factory) -> None:
    heli = VehicleFactory(name="Heli One")
    with pytest.raises(ValidationError) as refused:
        vehicle_update(
            vehicle=heli,
            config={"sensor_sources": {"CO2": {"source": "telemetry"}}},
            sensors=None,
            vvm=vvm_factory(),
        )
    assert refused.value.message_dict == {
        "sensor_sources": ["sensor 'CO2': telemetry needs a vehicle that speaks MAVLink "
                           "(its driver: mavlink)"]
    }  # fmt: skip
    heli.refresh_from_db()
    assert heli.sensor_sources == {}
    heli.driver, heli.driver_url = Driver.MAVLINK, "udpin:127.0.0.1:14550"
    heli.save()
    vehicle_update(
        vehicle=heli,
        config={"sensor_sources": {"Barometer": {"source": "telemetry"}}},
        sensors=None,
        vvm=vvm_factory(),
    )
    heli.refresh_from_db()
    assert heli.sensor_sources == {"Barometer": {"source": "telemetry"}}


# --- the mhz19 plug-in on a pty --------------------------------------------------------------


class FakeMHZ19:
    """The sensor's side of its serial line: answers each "read CO2" with ``ppm`` (None:
    stays silent; ``corrupt``: with a wrong checksum)."""

    def __init__(self, ppm: int | None = 612, *, corrupt: bool = False) -> None:
        self.ppm, self.corrupt = ppm, corrupt
        self.master, slave = os.openpty()
        self.port = os.ttyname(slave)
        self._slave = slave
        self.asked = 0
        self._thread = threading.Thread(target=self._serve, daemon=True)
        self._thread.start()

    def _serve(self) -> None:
        got = b""
        while True:
            try:
                got += os.read(self.master, 64)
            except OSError:
                return
            while READ_CO2 in got:
                got = got[got.index(READ_CO2) + len(READ_CO2) :]
                self.asked += 1
                if self.ppm is None:
                    continue
                frame = bytearray([0xFF, 0x86, self.ppm // 256, self.ppm % 256, 70, 0, 0, 0, 0])
                frame[8] = checksum(bytes(frame)) ^ (0xFF if self.corrupt else 0)
                os.write(self.master, b"\x00\x13" + bytes(frame))  # noise first, as on a line

    def close(self) -> None:
        os.close(self.master)
        os.close(self._slave)


@pytest.fixture
def sensor() -> Iterator[FakeMHZ19]:
    fake = FakeMHZ19()
    yield fake
    fake.close()


def test_the_mhz19_plugin_reads_the_sensor_over_its_serial_line(sensor: FakeMHZ19) -> None:
    assert plugin_class("mhz19") is MHZ19
    plugin = MHZ19(port=sensor.port)
    try:
        assert plugin.read(2.0) == {"value": 612.0}
        sensor.ppm = 1234
        assert plugin.read(2.0) == {"value": 1234.0}
        sensor.corrupt = True
        with pytest.raises(SensorFailure, match="an answer with a wrong checksum") as failed:
            plugin.read(2.0)
        assert sensor.port not in failed.value.reason  # the customer never sees the port
        sensor.ppm = None
        with pytest.raises(SensorFailure, match=r"no answer within 0\.3 s"):
            plugin.read(0.3)
    finally:
        plugin.close()
    with pytest.raises(PluginError, match="mhz19's baud must be a positive whole number"):
        MHZ19(port=sensor.port, baud="fast")


@pytest.mark.django_db
def test_a_sensor_on_the_vehicles_computer_serves_a_vvs_task(
    platform, ground_station, customer_a, sensor: FakeMHZ19
) -> None:
    heli = VehicleFactory(
        name="Heli One",
        sensor_sources={
            "CO2": {"source": PLUGIN, "plugin": "mhz19", "options": {"port": sensor.port}}
        },
    )
    platform.add_vehicle_loop(heli)
    vv = vv_submit(customer=customer_a, name="VV", program=ONE_TASK, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    reading = vv.storage.get(key="co2").value
    assert reading["sensor"] == "CO2" and reading["kind"] == "scalar"
    assert (reading["value"], reading["unit"]) == (612.0, "ppm")  # the sensor's, not the field's
    assert abs(reading["position"]["lat"] - 48.1111) < 1e-4 and reading["time"].endswith("Z")
    assert sensor.asked == 1


@pytest.mark.django_db
def test_a_reading_that_never_comes_fails_the_task_and_nothing_is_invented(
    platform, ground_station, customer_a
) -> None:
    silent = FakeMHZ19(ppm=None)
    try:
        heli = VehicleFactory(
            name="Heli One",
            sensor_sources={
                "CO2": {
                    "source": PLUGIN,
                    "plugin": "mhz19",
                    "options": {"port": silent.port},
                    "timeout_s": 0.3,
                }
            },
        )
        platform.add_vehicle_loop(heli)
        vv = vv_submit(customer=customer_a, name="VV", program=CATCHING, vvm=platform.vvm)
        platform.drain()
    finally:
        silent.close()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    message = "the vehicle took no reading: no answer within 0.3 s"
    assert vv.storage.get(key="error").value == f"TaskRejectedError: {message}"
    task = vv.tasks.get()
    assert (task.status, task.message, task.readings) == (TaskStatus.REJECTED, message, [])
    assert silent.asked == 1
