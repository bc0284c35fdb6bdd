"""MavSim's sensors over MAVLink, read from the simulated field where the vehicle is: the
autopilot's SCALED_PRESSURE (barometer and thermometer) and the companion computer's
NAMED_VALUE_FLOAT "CO2" and "NOx", from a seeded world a test can make differ from the
platform's own (seed 0)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import Any

import pytest

from fleet.catalog import DEFAULT_SDC
from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from fleet.simulation import SensorField, SensorSpec
from tests.fleet.mavlink.conftest import DEPOT, wait_until
from tests.fleet.mavlink.test_mavsim_guided import Station

SPEED = 40.0
SEED = 7
COMPANION = mavlink.MAV_COMP_ID_ONBOARD_COMPUTER


def sdc(quantity: str) -> SensorSpec:
    entry = next(e for e in DEFAULT_SDC if e["params"].get("quantity") == quantity)
    return SensorSpec(entry["name"], entry["kind"], entry["unit"], dict(entry["params"]))


def field_value(seed: int, quantity: str, sim: MavSim) -> float:
    """What the field says at the vehicle now (the readings' noise aside)."""
    sample = SensorField(seed).sample(sdc(quantity), sim.position(), sim.sim_now())
    return float(sample["value"])


@pytest.fixture
def sim(make_sim: Callable[..., MavSim]) -> MavSim:
    return make_sim(speed=SPEED, field_seed=SEED, payload=True)


@pytest.fixture
def gcs(port: int, sim: MavSim) -> Iterator[Station]:
    station = Station(port)
    yield station
    station.close()


def from_companion(kind: str, name: str | None = None) -> Callable[[Any], bool]:
    def match(msg: Any) -> bool:
        return msg.get_srcComponent() == COMPANION and (name is None or msg.name == name)

    return match


def test_the_barometer_reads_the_field_where_the_vehicle_is(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    first = gcs.wait("SCALED_PRESSURE")
    assert first.get_srcComponent() == 1  # the autopilot's own barometer
    assert abs(first.press_abs - field_value(SEED, "pressure", sim)) < 0.1  # hPa
    assert abs(first.temperature - field_value(SEED, "temperature", sim) * 100) < 15  # cdegC
    # Another world than the platform's own simulated field (seed 0).
    assert abs(field_value(0, "pressure", sim) - first.press_abs) > 1.0

    # 2 Hz unless asked otherwise.
    second = gcs.wait("SCALED_PRESSURE")
    assert 0.35 < (second.time_boot_ms - first.time_boot_ms) / 1000 < 0.7
    pressure = mavlink.MAVLINK_MSG_ID_SCALED_PRESSURE
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, pressure, 100_000) == 0
    gcs.wait("SCALED_PRESSURE")
    last = [gcs.wait("SCALED_PRESSURE") for _ in range(6)]
    assert 0.3 < (last[-1].time_boot_ms - last[0].time_boot_ms) / 1000 < 0.8

    # Aloft it reads the air up there: about 12 hPa less at 100 m.
    gcs.take_off(sim, 100)
    target = offset(DEPOT, north_m=400, east_m=300, up_m=100)
    gcs.mav.set_position_target_global_int_send(
        0, 1, 1, mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 0b110111111000,
        round(target.lat * 1e7), round(target.lng * 1e7), 100, 0, 0, 0, 0, 0, 0, 0, 0,
    )  # fmt: skip
    wait_until(lambda: distance_m(sim.position(), target) < 0.5, what="the hover over there")
    expected = field_value(SEED, "pressure", sim)
    # (Older readings still queued on the ground station's socket are passed over.)
    aloft = gcs.wait("SCALED_PRESSURE", lambda m: abs(m.press_abs - expected) < 0.1, timeout=3)
    assert first.press_abs - aloft.press_abs > 10


def test_the_companion_sends_co2_and_nox(sim: MavSim, gcs: Station) -> None:
    beat = gcs.wait("HEARTBEAT", from_companion("HEARTBEAT"))
    assert beat.type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER
    assert beat.autopilot == mavlink.MAV_AUTOPILOT_INVALID
    co2 = gcs.wait("NAMED_VALUE_FLOAT", from_companion("NAMED_VALUE_FLOAT", "CO2"))
    nox = gcs.wait("NAMED_VALUE_FLOAT", from_companion("NAMED_VALUE_FLOAT", "NOx"))
    assert abs(co2.value - field_value(SEED, "co2", sim)) < 2.0  # ppm
    assert abs(nox.value - field_value(SEED, "nox", sim)) < 1.0  # ppb
    assert 350 < co2.value < 2000 and 10 <= nox.value <= 80
    again = gcs.wait("NAMED_VALUE_FLOAT", from_companion("NAMED_VALUE_FLOAT", "CO2"))
    assert 0.35 < (again.time_boot_ms - co2.time_boot_ms) / 1000 < 0.7  # 2 Hz
    # The companion answers commands addressed to it, if only to say it cannot.
    gcs.mav.command_long_send(1, COMPANION, mavlink.MAV_CMD_DO_SET_ROI_NONE, 0, 0, 0, 0, 0, 0, 0, 0)
    ack = gcs.wait("COMMAND_ACK", lambda m: m.get_srcComponent() == COMPANION)
    assert ack.result == mavlink.MAV_RESULT_UNSUPPORTED


def test_without_payload_only_the_autopilot_speaks(
    make_sim: Callable[..., MavSim], port: int
) -> None:
    sim = make_sim(speed=SPEED)
    station = Station(port)
    try:
        station.wait("HEARTBEAT")
        beats = [station.wait("HEARTBEAT") for _ in range(2)]
        assert {m.get_srcComponent() for m in beats} == {1}
        assert sim.camera_port is None
    finally:
        station.close()


def test_the_gps_receiver_reports_its_own_fix(sim: MavSim, gcs: Station) -> None:
    gcs.wait("HEARTBEAT")
    gps = mavlink.MAVLINK_MSG_ID_GPS_RAW_INT
    assert gcs.command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, gps, 200_000) == 0
    raw = gcs.wait("GPS_RAW_INT")
    assert raw.fix_type == mavlink.GPS_FIX_TYPE_3D_FIX
    assert 7 <= raw.satellites_visible <= 14 and 60 <= raw.eph <= 150  # HDOP 0.6 to 1.5
    # A few metres off the true position, as the field's GPS sensor is.
    fix = Position(raw.lat / 1e7, raw.lon / 1e7, raw.alt / 1000)
    assert 0 < distance_m(fix, DEPOT) < 5.0
