"""Flight logs kept through Django's storage, and deleted after CPCC_FLIGHT_LOG_DAYS."""

from __future__ import annotations

import datetime
import io
from pathlib import Path
from typing import Any

import pytest
from django.core.files.storage import default_storage
from django.core.management import CommandError, call_command
from django.utils import timezone
from pymavlink import mavutil

from fleet.mavlink.tlog_sim import simulated_tlog
from fleet.models import Flight
from tests.factories import VehicleFactory
from vvm_worker.services.flight_logs import flight_log_save, flight_logs_prune

pytestmark = pytest.mark.django_db

TRACK = [(0.0, 48.1135, 12.86, 0.0), (10.0, 48.1135, 12.86, 30.0), (20.0, 48.112, 12.861, 30.0)]


def a_flight(name: str, *, ended_days_ago: float | None) -> Flight:
    vehicle = VehicleFactory(name=name)
    now = timezone.now()
    ended = None if ended_days_ago is None else now - datetime.timedelta(days=ended_days_ago)
    return Flight.objects.create(
        vehicle=vehicle,
        started=(ended or now) - datetime.timedelta(minutes=20),
        started_s=0.0,
        ended=ended,
        ended_s=None if ended is None else 1200.0,
    )


def test_a_saved_log_is_the_flights_file_and_opens_in_pymavlink(tmp_path: Path) -> None:
    flight = a_flight("Heli One", ended_days_ago=0)
    data = simulated_tlog(TRACK, epoch_s=1.7e9, system_id=1, battery_start=1.0, battery_end=0.9)
    flight_log_save(flight=flight, data=data)

    flight.refresh_from_db()
    assert flight.log.name == f"flights/heli-one-{flight.pk}.tlog"
    assert default_storage.open(flight.log.name).read() == data
    log = mavutil.mavlink_connection(default_storage.path(flight.log.name))
    assert log.recv_match(type="GLOBAL_POSITION_INT").lat == 481135000

    # Saved again (a retried landing, from a recorder's file): one file, the new bytes.
    flight_log_save(flight=flight, data=io.BytesIO(data[:100]))
    flight.refresh_from_db()
    assert flight.log.name == f"flights/heli-one-{flight.pk}.tlog"
    assert default_storage.open(flight.log.name).read() == data[:100]
    assert default_storage.listdir("flights")[1] == [f"heli-one-{flight.pk}.tlog"]


def test_prune_deletes_the_old_logs_and_keeps_the_recent_ones(settings: Any) -> None:
    settings.CPCC_FLIGHT_LOG_DAYS = 30
    old = a_flight("Old", ended_days_ago=31)
    recent = a_flight("Recent", ended_days_ago=29)
    flying = a_flight("Flying", ended_days_ago=None)
    for flight in (old, recent, flying):
        flight_log_save(flight=flight, data=b"tlog")
    old_name = Flight.objects.get(pk=old.pk).log.name

    assert flight_logs_prune() == 1
    assert not default_storage.exists(old_name)
    assert Flight.objects.get(pk=old.pk).log.name == ""  # the flight itself stays
    assert Flight.objects.get(pk=recent.pk).log and Flight.objects.get(pk=flying.pk).log
    assert flight_logs_prune() == 0  # twice is harmless

    # Two days on, the recent one is old too; the command does the same.
    out = io.StringIO()
    call_command("flightlogs", "--prune", stdout=out)
    assert out.getvalue().startswith("0 flight log(s) deleted")
    assert flight_logs_prune(now=timezone.now() + datetime.timedelta(days=2)) == 1
    assert Flight.objects.get(pk=flying.pk).log  # still flying: kept
    with pytest.raises(CommandError, match="--prune"):
        call_command("flightlogs")
