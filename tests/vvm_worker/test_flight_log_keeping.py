"""An RV worker keeps each flight's telemetry log once its landing commits (issue 58): the
MAVLink driver's recording; a simulated RV's is the simulator's messages along the flight's
track, made when asked for; ``simulate`` keeps none. (The MAVLink worker's log end to end:
test_mavlink_worker.py.)"""

from __future__ import annotations

import datetime as dt
import io

import pytest
from django.db import transaction
from django.utils import timezone
from pymavlink import mavutil

from fleet.models import Flight
from tests.factories import VehicleFactory
from vvm_worker.control import Landing
from vvm_worker.executor import DatabaseStore
from vvm_worker.services.flight_logs import flight_log_kept, flight_log_simulated

pytestmark = pytest.mark.django_db

TRACK = (
    (100.0, 48.1135, 12.8600, 0.0, 95.0),
    (110.0, 48.1135, 12.8600, 20.0, 94.0),
    (160.0, 48.1160, 12.8640, 20.0, 90.0),
    (200.0, 48.1135, 12.8600, 0.0, 87.0),
)


def _landing(log=None) -> Landing:
    return Landing(
        took_off_s=100.0,
        t_s=200.0,
        how="landed_home",
        distance_m=800.0,
        flight_s=100.0,
        max_alt_m=20.0,
        battery_start_pct=95.0,
        battery_end_pct=87.0,
        track=TRACK,
        log=log,
    )


@pytest.fixture
def flight(settings, tmp_path):
    settings.MEDIA_ROOT = tmp_path
    vehicle = VehicleFactory(name="Heli One")
    return Flight.objects.create(vehicle=vehicle, started=timezone.now(), started_s=100.0)


def _read(path: str) -> list[tuple[float, float, float, float]]:
    log = mavutil.mavlink_connection(path)
    found = []
    while (m := log.recv_match(type="GLOBAL_POSITION_INT")) is not None:
        found.append((m._timestamp, m.lat / 1e7, m.lon / 1e7, m.relative_alt / 1000))
    return found


def test_a_simulated_rvs_flight_log_is_the_simulators_messages_along_its_track(
    flight, vvm_factory, django_capture_on_commit_callbacks, tmp_path
) -> None:
    """Nothing is stored at the landing (the worker spends nothing on it): the log is made
    from the flight's track when asked for."""
    store = DatabaseStore(vehicle_id=flight.vehicle_id, vvm=vvm_factory())
    with django_capture_on_commit_callbacks(execute=True):
        store._keep_logs([_landing()])
    flight.refresh_from_db()
    assert not flight.log
    flight.track = [list(p) for p in TRACK]
    flight.battery_start_pct, flight.battery_end_pct = 95.0, 87.0
    assert flight_log_kept(flight=flight)
    path = tmp_path / "sim.tlog"
    path.write_bytes(flight_log_simulated(flight=flight))
    track = _read(str(path))
    epoch_s = flight.started.timestamp() - flight.started_s
    assert track[0][0] == pytest.approx(epoch_s + 100.0, abs=0.5)
    assert track[-1][0] == pytest.approx(epoch_s + 200.0, abs=0.5)
    assert track[0][1:3] == pytest.approx((48.1135, 12.86), abs=1e-6)
    assert max(alt for *_, alt in track) == pytest.approx(20.0, abs=0.1)
    assert any(abs(lat - 48.116) < 1e-5 and abs(lng - 12.864) < 1e-5 for _, lat, lng, _ in track)
    flight.ended = timezone.now() - dt.timedelta(days=1000)
    assert not flight_log_kept(flight=flight), "older than CPCC_FLIGHT_LOG_DAYS: none"


def test_a_mavlink_rvs_recording_is_kept_as_it_is(
    flight, vvm_factory, django_capture_on_commit_callbacks
) -> None:
    recorded = b"not parsed: kept byte for byte"
    store = DatabaseStore(vehicle_id=flight.vehicle_id, vvm=vvm_factory())
    recording = io.BytesIO(recorded)
    with django_capture_on_commit_callbacks(execute=True):
        store._keep_logs([_landing(log=recording)])
    flight.refresh_from_db()
    with flight.log.open("rb") as kept:
        assert kept.read() == recorded
    assert recording.closed


def test_a_rolled_back_landing_keeps_no_log_and_simulate_keeps_none(
    flight, vvm_factory, django_capture_on_commit_callbacks
) -> None:
    store = DatabaseStore(vehicle_id=flight.vehicle_id, vvm=vvm_factory())
    with django_capture_on_commit_callbacks(execute=True) as kept, transaction.atomic():
        store._keep_logs([_landing(log=io.BytesIO(b"recorded"))])
        transaction.set_rollback(True)
    assert not kept
    flight.refresh_from_db()
    assert not flight.log
    deferred = DatabaseStore(vehicle_id=flight.vehicle_id, vvm=vvm_factory(), defer_reports=True)
    with django_capture_on_commit_callbacks(execute=True) as kept:
        deferred._keep_logs([_landing(log=io.BytesIO(b"recorded"))])
    assert not kept
    flight.refresh_from_db()
    assert not flight.log
