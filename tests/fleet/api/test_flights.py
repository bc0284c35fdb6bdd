"""The flights over the staff API (issue 58): the list with its filters, one flight, its log,
the CSV of a period (read back with csv.DictReader) and an RV's logbook."""

from __future__ import annotations

import csv
import datetime as dt
import io

import pytest
from django.core.files.base import ContentFile
from pymavlink import mavutil

from fleet.models import Flight, FlightEnd
from tests.api_fixtures import token_client
from tests.factories import UserFactory, VehicleFactory

pytestmark = pytest.mark.django_db

T0 = dt.datetime(2026, 12, 1, 9, 0, tzinfo=dt.UTC)


def _flight(vehicle, minutes_after: float, **fields) -> Flight:
    started = T0 + dt.timedelta(minutes=minutes_after)
    values = {
        "ended": started + dt.timedelta(minutes=10),
        "duration_s": 600.0,
        "distance_m": 2500.0,
        "max_alt_m": 60.0,
        "ended_how": FlightEnd.LANDED_HOME,
        "pilot_name": "pia",
        "tasks_served": 3,
        "customers": [{"id": 1, "name": "Customer A"}, {"id": 2, "name": "Customer B"}],
        "battery_start_pct": 98.0,
        "battery_end_pct": 61.0,
    } | fields
    return Flight.objects.create(
        vehicle=vehicle, started=started, started_s=started.timestamp(), **values
    )


@pytest.fixture
def flights():
    one, two = VehicleFactory(name="Heli One"), VehicleFactory(name="Heli Two")
    return (
        one,
        two,
        [
            _flight(one, 0),
            _flight(one, 60, ended_how=FlightEnd.OPERATOR, battery_name="BAT-0042"),
            _flight(two, 120),
            _flight(one, 24 * 60, ended=None, duration_s=None, distance_m=None, ended_how=""),
        ],
    )


def test_staff_list_the_flights_newest_first_filtered(api_staff, flights) -> None:
    _, two, made = flights
    listed = api_staff.get("/api/v1/flights/").json()
    assert [f["id"] for f in listed["results"]] == [f.pk for f in reversed(made)]
    assert listed["results"][0]["ended"] is None  # still in the air
    mine = api_staff.get(f"/api/v1/flights/?vehicle={two.pk}").json()["results"]
    assert [(f["vehicle"], f["pilot_in_command"], f["tasks_served"]) for f in mine] == [
        ("Heli Two", "pia", 3)
    ]
    day = api_staff.get(
        "/api/v1/flights/", {"from": "2026-12-01T09:30:00Z", "to": "2026-12-02T00:00:00Z"}
    ).json()["results"]
    assert [f["id"] for f in day] == [made[2].pk, made[1].pk]
    bad = api_staff.get("/api/v1/flights/?from=yesterday")
    assert bad.status_code == 400 and "from" in bad.json()["detail"]


def test_one_flight_and_its_log(api_staff, flights, settings, tmp_path) -> None:
    settings.MEDIA_ROOT = tmp_path
    _, _, made = flights
    flight = made[1]
    shown = api_staff.get(f"/api/v1/flights/{flight.pk}/").json()
    assert shown["ended_how"] == "operator" and shown["battery_name"] == "BAT-0042"
    assert shown["log"] is None
    assert api_staff.get(f"/api/v1/flights/{flight.pk}/log.tlog").status_code == 404
    flight.log.save("flights/heli-one.tlog", ContentFile(b"\x00" * 8 + b"\xfe\x09"))
    assert api_staff.get(f"/api/v1/flights/{flight.pk}/").json()["log"].endswith("log.tlog")
    response = api_staff.get(f"/api/v1/flights/{flight.pk}/log.tlog")
    assert response.status_code == 200
    assert b"".join(response.streaming_content) == b"\x00" * 8 + b"\xfe\x09"
    assert ".tlog" in response["Content-Disposition"]
    assert api_staff.get("/api/v1/flights/987654/").status_code == 404
    # A simulated RV's flight: its log is the simulator's messages along its track.
    simulated = made[0]
    simulated.track = [[0.0, 48.11, 12.86, 0.0, 90.0], [60.0, 48.112, 12.862, 30.0, 85.0]]
    simulated.started_s = 0.0
    simulated.save()
    assert api_staff.get(f"/api/v1/flights/{simulated.pk}/").json()["log"] is not None
    tlog = api_staff.get(f"/api/v1/flights/{simulated.pk}/log.tlog")
    path = tmp_path / "simulated.tlog"
    path.write_bytes(tlog.content)
    positions = mavutil.mavlink_connection(str(path))
    first = positions.recv_match(type="GLOBAL_POSITION_INT")
    assert (first.lat, first.lon) == (481100000, 128600000)
    assert first._timestamp == pytest.approx(simulated.started.timestamp(), abs=0.5)


def test_the_csv_of_a_period_opens_in_a_spreadsheet(api_staff, flights) -> None:
    response = api_staff.get("/api/v1/flights/export.csv", {"to": "2026-12-01T23:00:00Z"})
    assert response.status_code == 200 and response["Content-Type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(response.content.decode())))
    assert [(r["vehicle"], r["take_off_utc"]) for r in rows] == [
        ("Heli One", "2026-12-01T09:00:00Z"),
        ("Heli One", "2026-12-01T10:00:00Z"),
        ("Heli Two", "2026-12-01T11:00:00Z"),
    ]
    first = rows[0]
    assert first["duration_min"] == "10.00" and first["distance_km"] == "2.500"
    assert first["customers"] == "Customer A; Customer B"
    assert first["ended_how"] == "Landed at home" and first["pilot_in_command"] == "pia"


def test_an_rvs_logbook(api_staff, flights) -> None:
    one, _, _ = flights
    book = api_staff.get(f"/api/v1/vehicles/{one.pk}/logbook/").json()
    assert book == {
        "flights": 2,
        "take_offs": 3,
        "landings": 2,
        "flight_hours": round(1200 / 3600, 3),
        "distance_km": 5.0,
        "last_flight": "2026-12-02T09:00:00Z",
        "in_flight": True,
        "batteries": [],  # none reported (tests/fleet/api/test_batteries.py)
    }


def test_customers_never_see_the_flights(api_a, flights) -> None:
    one, _, made = flights
    for url in (
        "/api/v1/flights/",
        f"/api/v1/flights/{made[0].pk}/",
        "/api/v1/flights/export.csv",
        f"/api/v1/vehicles/{one.pk}/logbook/",
    ):
        assert api_a.get(url).status_code == 403, url
    pilot = UserFactory(username="pia", is_staff=True)
    assert token_client(pilot).get("/api/v1/flights/").status_code == 403  # in no group
