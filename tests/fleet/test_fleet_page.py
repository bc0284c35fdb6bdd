"""The fleet overview as operators run the fleet from it (issue 26): every RV with its battery
(a number, or why there is none), its actions, each asked first and audited; the page is for
staff who may change vehicles only."""

from __future__ import annotations

import re

import pytest
from auditlog.models import LogEntry
from django.urls import reverse

import fleet.admin
from fleet.models import Driver, Vehicle, VehicleStatus
from tests.factories import UserFactory, VehicleFactory

pytestmark = pytest.mark.django_db

OVERVIEW = "/admin/fleet/vehicle/overview/"


@pytest.fixture
def recorded(monkeypatch, vvm_factory):
    """The admin's VVM with a dispatcher that records whom it tells (no worker runs)."""
    vvm = vvm_factory()
    monkeypatch.setattr(fleet.admin, "platform_vvm", lambda: vvm)
    return vvm


def _row(page: str, name: str) -> str:
    found = re.search(rf'<tr data-vehicle="{re.escape(name)}".*?</tr>', page, re.DOTALL)
    assert found, f"no row for {name}"
    return found.group(0)


def _cell(row: str, name: str) -> str:
    found = re.search(rf'data-cell="{name}"[^>]*>(.*?)</(?:td|div)>', row, re.DOTALL)
    assert found, f"no {name} cell"
    return " ".join(re.sub(r"<[^>]+>", " ", found.group(1)).split())


def test_every_battery_is_a_number_or_says_why_there_is_none(client, staff) -> None:
    VehicleFactory(name="Heli Sim")  # no battery_s
    VehicleFactory(name="Heli Timed", battery_s=200.0, flight_s=50.0)
    VehicleFactory(name="Heli Link", driver=Driver.MAVLINK, driver_url="udpin:0.0.0.0:14550")
    reported = VehicleFactory(name="Heli Told", driver=Driver.MAVLINK, driver_url="tcp:x:1")
    Vehicle.objects.filter(pk=reported.pk).update(health={"link": "up", "battery_pct": 42})
    client.force_login(staff)
    page = client.get(OVERVIEW).text
    assert "not set" not in page
    cells = {name: _cell(_row(page, name), "battery") for name in
             ("Heli Sim", "Heli Timed", "Heli Link", "Heli Told")}  # fmt: skip
    assert cells == {
        "Heli Sim": "n/a simulated without a battery (no battery_s set)",
        "Heli Timed": "75 %",
        "Heli Link": "n/a its worker has not reported yet",
        "Heli Told": "42 %",
    }
    row = _row(page, "Heli Told")
    assert _cell(row, "link") == "link up"
    assert _cell(row, "altitude") == "0 m"


def test_each_rv_has_its_actions_each_with_the_question_it_asks(client, staff) -> None:
    heli = VehicleFactory(name="Heli One")
    Vehicle.objects.filter(pk=heli.pk).update(status=VehicleStatus.MAINTENANCE)
    client.force_login(staff)
    page = client.get(OVERVIEW).text
    found = re.search(r'<tr [^>]*data-actions-for="Heli One">.*?</tr>', page, re.DOTALL)
    assert found, "no actions for Heli One"
    row = found.group(0)
    assert f'action="{reverse("admin:fleet_vehicle_act", args=[heli.pk])}"' in row
    buttons = re.findall(r'<button type="submit" name="act" value="(\w+)"[^>]*?( disabled)?>', row)
    assert buttons == [
        ("maintenance", " disabled"),  # in maintenance already
        ("return", ""),
        ("return_home", ""),
        ("land", ""),
        ("take_duty", ""),  # (a superuser may take any RV on duty)
    ]
    assert 'data-confirm="Land Heli One now, where it is? It goes into maintenance' in row


def test_an_action_is_asked_first_then_done_and_audited(client, staff, recorded) -> None:
    heli = VehicleFactory(name="Heli One")
    act = reverse("admin:fleet_vehicle_act", args=[heli.pk])
    client.force_login(staff)
    asked = client.post(act, {"act": "return_home"})
    assert asked.status_code == 200
    assert "Send Heli One home now?" in asked.text
    assert 'name="confirmed" value="yes"' in asked.text
    heli.refresh_from_db()
    assert (heli.status, heli.command) == (VehicleStatus.ACTIVE, ""), "nothing done yet"

    done = client.post(act, {"act": "return_home", "confirmed": "yes"}, follow=True)
    assert done.redirect_chain == [(OVERVIEW, 302)]
    assert "Heli One: return home now, sent to its worker" in done.text
    heli.refresh_from_db()
    assert (heli.status, heli.command) == (VehicleStatus.MAINTENANCE, "return_home")
    assert heli.status_reason == "return home now: asked by operator on the fleet overview"
    assert recorded.dispatcher.vehicles == [heli.pk], "its worker is told"
    entry = LogEntry.objects.get_for_object(heli).filter(action=LogEntry.Action.UPDATE).first()
    assert entry is not None and entry.actor == staff
    row = _row(done.text, "Heli One")
    assert "Return home now, asked" in row and "waiting for its worker" in row

    back = client.post(act, {"act": "return", "confirmed": "yes"})
    assert back.status_code == 302
    heli.refresh_from_db()
    assert heli.status == VehicleStatus.ACTIVE
    assert heli.status_reason == "set by operator on the fleet overview"


def test_bad_actions_and_methods_are_refused_saying_why(client, staff, recorded) -> None:
    heli = VehicleFactory(name="Heli One")
    act = reverse("admin:fleet_vehicle_act", args=[heli.pk])
    client.force_login(staff)
    bad = client.post(act, {"act": "self_destruct", "confirmed": "yes"})
    assert bad.status_code == 400
    assert "'self_destruct' is not an action; one of maintenance, return" in bad.text
    assert client.get(act).status_code == 405
    missing = reverse("admin:fleet_vehicle_act", args=[999])
    assert client.post(missing, {"act": "land", "confirmed": "yes"}).status_code == 404
    assert Vehicle.objects.get(pk=heli.pk).status == VehicleStatus.ACTIVE


def test_customers_and_staff_without_permission_cannot_act(client, user_a, recorded) -> None:
    heli = VehicleFactory(name="Heli One")
    act = reverse("admin:fleet_vehicle_act", args=[heli.pk])
    client.force_login(user_a)
    response = client.post(act, {"act": "land", "confirmed": "yes"})
    assert response.status_code == 302 and "/admin/login/" in response["Location"]
    client.force_login(UserFactory(username="helpdesk", is_staff=True))
    assert client.post(act, {"act": "land", "confirmed": "yes"}).status_code == 403
    heli.refresh_from_db()
    assert (heli.status, heli.command) == (VehicleStatus.ACTIVE, "")
