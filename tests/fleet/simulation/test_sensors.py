"""Simulated sensor fields: plausible, deterministic, spatially structured readings."""

import statistics
import subprocess
import sys
from pathlib import Path

import pytest

from fleet.geo import Position, distance_m, offset
from fleet.simulation import SensorField, SensorSpec

ORIGIN = Position(47.07, 15.44, 0.0)
CO2 = SensorSpec("CO2", "scalar", "ppm", {"quantity": "co2"})
THERMOMETER = SensorSpec("Thermometer", "scalar", "°C", {"quantity": "temperature"})
NOX = SensorSpec("NOx", "scalar", "ppb", {"quantity": "nox"})
BAROMETER = SensorSpec("Barometer", "scalar", "hPa", {"quantity": "pressure"})
ALTIMETER = SensorSpec("Altimeter", "scalar", "m", {"quantity": "altitude"})
BATTERY = SensorSpec("Battery", "scalar", "%", {"quantity": "battery"})
GPS = SensorSpec("GPS", "gps")
CAMERA = SensorSpec("Camera 640x480", "camera", params={"width": 640, "height": 480})
SCALARS = [CO2, THERMOMETER, NOX, BAROMETER, ALTIMETER, BATTERY]


def _grid(spacing_m: float, n: int, alt: float = 0.0) -> list[Position]:
    return [
        offset(ORIGIN, north_m=spacing_m * i, east_m=spacing_m * j, up_m=alt)
        for i in range(n)
        for j in range(n)
    ]


def _value(field: SensorField, sensor: SensorSpec, position: Position, t: float = 0.0) -> float:
    value = field.sample(sensor, position, t)["value"]
    assert isinstance(value, float)
    return value


@pytest.mark.parametrize(
    ("sensor", "low", "high"),
    [
        (CO2, 400.0, 1000.0),
        (THERMOMETER, 6.0, 24.0),
        (NOX, 10.0, 80.0),
        (BAROMETER, 985.0, 1040.0),
    ],
)
def test_scalar_values_are_plausible_over_a_whole_area(
    sensor: SensorSpec, low: float, high: float
) -> None:
    field = SensorField(7)
    values = [_value(field, sensor, p, 3600.0) for p in _grid(500.0, 12, alt=10.0)]
    assert low <= min(values)
    assert max(values) <= high


def test_co2_is_near_background_with_plumes_somewhere() -> None:
    field = SensorField(3)
    values = [_value(field, CO2, p) for p in _grid(400.0, 20)]
    assert 410.0 < statistics.median(values) < 425.0
    assert max(values) > 480.0


def test_readings_have_the_shape_and_unit_of_their_kind() -> None:
    field = SensorField(1)
    reading = field.sample(CO2, ORIGIN, 0.0)
    assert set(reading) == {"value", "unit"}
    assert reading["unit"] == "ppm"
    assert (
        field.sample(SensorSpec("T", "scalar", params={"quantity": "temperature"}), ORIGIN, 0.0)[
            "unit"
        ]
        == "°C"
    )
    gps = field.sample(GPS, ORIGIN, 0.0)
    assert set(gps) == {"lat", "lng", "alt", "satellites", "hdop"}
    assert isinstance(gps["satellites"], int)
    assert field.sample(CAMERA, ORIGIN, 0.0) == {"width": 640, "height": 480, "format": "png"}


def test_same_seed_gives_the_same_readings() -> None:
    position = offset(ORIGIN, north_m=123.0, east_m=-45.0, up_m=33.0)
    first, second = SensorField(11), SensorField(11)
    for sensor in [*SCALARS, GPS]:
        assert first.sample(sensor, position, 17.5) == second.sample(sensor, position, 17.5)


def test_another_seed_gives_another_world() -> None:
    points = _grid(300.0, 4)
    for sensor in (CO2, THERMOMETER, NOX):
        a = [_value(SensorField(1), sensor, p) for p in points]
        b = [_value(SensorField(2), sensor, p) for p in points]
        assert a != b


@pytest.mark.parametrize("sensor", [CO2, THERMOMETER, NOX])
def test_fields_vary_across_100_m_and_are_smooth_at_short_range(sensor: SensorSpec) -> None:
    field = SensorField(5)
    points = _grid(700.0, 5, alt=20.0)
    near = [
        abs(_value(field, sensor, p) - _value(field, sensor, offset(p, north_m=2.0, east_m=0.0)))
        for p in points
    ]
    apart = [
        abs(_value(field, sensor, p) - _value(field, sensor, offset(p, north_m=100.0, east_m=0.0)))
        for p in points
    ]
    assert sum(d > 0.0 for d in apart) >= len(points) - 2
    assert statistics.mean(near) < statistics.mean(apart)


def test_pressure_follows_the_barometric_formula_with_altitude() -> None:
    field = SensorField(4)
    ground = _value(field, BAROMETER, ORIGIN)
    at_50 = _value(field, BAROMETER, ORIGIN.with_alt(50.0))
    at_500 = _value(field, BAROMETER, ORIGIN.with_alt(500.0))
    assert ground > at_50 > at_500
    # ISA near sea level: about 0.12 hPa per metre.
    assert ground - at_50 == pytest.approx(6.0, abs=0.4)
    assert ground - at_500 == pytest.approx(58.0, abs=3.0)


def test_temperature_falls_with_the_standard_lapse_rate() -> None:
    field = SensorField(4)
    ground = _value(field, THERMOMETER, ORIGIN)
    high = _value(field, THERMOMETER, ORIGIN.with_alt(1000.0))
    assert ground - high == pytest.approx(6.5, abs=0.15)


def test_temperature_drifts_over_the_day() -> None:
    field = SensorField(4)
    readings = {_value(field, THERMOMETER, ORIGIN, hour * 3600.0) for hour in range(0, 24, 3)}
    assert max(readings) - min(readings) > 1.0


def test_co2_is_lower_aloft() -> None:
    field = SensorField(3)
    points = _grid(400.0, 6)
    ground = statistics.mean(_value(field, CO2, p) for p in points)
    aloft = statistics.mean(_value(field, CO2, p.with_alt(300.0)) for p in points)
    assert aloft < ground


def test_altimeter_reads_the_altitude_with_small_noise() -> None:
    field = SensorField(9)
    errors = [_value(field, ALTIMETER, ORIGIN.with_alt(42.0), t) - 42.0 for t in range(0, 200, 10)]
    assert all(abs(e) <= 0.5 for e in errors)
    assert len(set(errors)) > 5


def test_battery_reads_the_remaining_fraction_as_percent() -> None:
    field = SensorField(9)
    assert field.sample(BATTERY, ORIGIN, 0.0, battery_fraction=0.42)["value"] == 42.0
    assert field.sample(BATTERY, ORIGIN, 0.0)["value"] == 100.0
    assert field.sample(BATTERY, ORIGIN, 0.0, battery_fraction=-0.3)["value"] == 0.0


def test_gps_fix_is_within_a_few_metres_of_the_true_position() -> None:
    field = SensorField(13)
    errors = []
    for k, truth in enumerate(_grid(250.0, 5, alt=30.0)):
        fix = field.sample(GPS, truth, float(k))
        assert 4 <= fix["satellites"] <= 16
        assert 0.5 <= fix["hdop"] <= 2.0
        errors.append(distance_m(truth, Position(fix["lat"], fix["lng"], fix["alt"])))
    assert max(errors) < 5.0
    assert statistics.mean(errors) > 0.1  # there is noise: a GPS is not a ruler


def test_unknown_kind_and_quantity_are_refused_by_name() -> None:
    field = SensorField(1)
    with pytest.raises(ValueError, match="'lidar'"):
        field.sample(SensorSpec("Scanner", "lidar"), ORIGIN, 0.0)
    with pytest.raises(ValueError, match="'humidity'"):
        field.sample(SensorSpec("Hygro", "scalar", params={"quantity": "humidity"}), ORIGIN, 0.0)
    with pytest.raises(ValueError, match="view"):
        field.sample(SensorSpec("Cam", "camera", params={"view": "rear"}), ORIGIN, 0.0)


def test_simulation_core_imports_no_django() -> None:
    code = "import sys, fleet.simulation; sys.exit('django' in sys.modules)"
    root = Path(__file__).resolve().parents[3]
    result = subprocess.run([sys.executable, "-c", code], cwd=root, check=False)
    assert result.returncode == 0
