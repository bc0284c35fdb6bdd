"""Pilots in the admin (issue 57): a fleet manager assigns an RV's pilots; on the fleet
overview a pilot operates the RVs they are assigned (and is refused on another), takes one on
duty and hands it over; support looks without acting; every command is audited with the pilot
in command; pilots' duties and take-offs are kept read-only."""

from __future__ import annotations

import re

import pytest
from auditlog.models import LogEntry
from django.contrib.auth.models import Group
from django.urls import reverse
from django.utils import timezone

import fleet.admin
from accounts.roles import FLEET_MANAGER, PILOT, SUPPORT
from fleet.models import Flight, PilotDuty, Vehicle, VehicleStatus
from tests.admin_forms import form_as_shown
from tests.factories import UserFactory, VehicleFactory
from vvm_worker.services import vehicle_take_duty

pytestmark = pytest.mark.django_db

OVERVIEW = "/admin/fleet/vehicle/overview/"


@pytest.fixture
def recorded(monkeypatch, vvm_factory):
    """The admin's VVM with a dispatcher that records whom it tells (no worker runs)."""
    vvm = vvm_factory()
    monkeypatch.setattr(fleet.admin, "platform_vvm", lambda: vvm)
    return vvm


def member(username: str, group: str):
    user = UserFactory(username=username, is_staff=True)
    user.groups.add(Group.objects.get(name=group))
    return user


@pytest.fixture
def pilot(db):
    return member("pilot-one", PILOT)


@pytest.fixture
def heli(pilot):
    """Heli One, which pilot-one (and pilot-two) may fly."""
    vehicle = VehicleFactory(name="Heli One")
    vehicle.pilots.add(pilot, member("pilot-two", PILOT))
    return vehicle


@pytest.fixture
def elsewhere(db):
    """An RV none of the test's pilots may fly."""
    return VehicleFactory(name="Heli Elsewhere")


def act(client, vehicle: Vehicle, act: str, **more: str):
    url = reverse("admin:fleet_vehicle_act", args=[vehicle.pk])
    return client.post(url, {"act": act, "confirmed": "yes", **more})


def actions_row(page: str, name: str) -> str:
    found = re.search(rf'<tr [^>]*data-actions-for="{re.escape(name)}">.*?</tr>', page, re.DOTALL)
    assert found, f"no actions row for {name}"
    return found.group(0)


def buttons(page: str, name: str) -> list[str]:
    row = actions_row(page, name)
    return re.findall(r'<button type="submit" name="act" value="(\w+)"', row)


def pilot_cell(page: str, name: str) -> str:
    row = re.search(rf'<tr data-vehicle="{re.escape(name)}".*?</tr>', page, re.DOTALL)
    assert row, f"no row for {name}"
    cell = re.search(r'data-cell="pilot"[^>]*>(.*?)</td>', row.group(0), re.DOTALL)
    assert cell, f"no pilot cell for {name}"
    return " ".join(re.sub(r"<[^>]+>", " ", cell.group(1)).split())


def test_a_pilot_commands_an_assigned_rv_and_is_refused_on_another(
    client, pilot, heli, elsewhere, recorded
) -> None:
    client.force_login(pilot)
    page = client.get(OVERVIEW)
    assert page.status_code == 200
    assert buttons(page.text, "Heli One") == [
        "maintenance",
        "return",
        "return_home",
        "land",
        "take_duty",
    ]
    assert buttons(page.text, "Heli Elsewhere") == [], "the page hides what they may not do"

    done = act(client, heli, "land")
    assert done.status_code == 302
    heli.refresh_from_db()
    assert (heli.status, heli.command) == (VehicleStatus.MAINTENANCE, "land")
    assert heli.status_reason == "land now: asked by pilot-one on the fleet overview"

    for refused in ("land", "maintenance", "return_home", "take_duty", "hand_over"):
        response = act(client, elsewhere, refused)
        assert response.status_code == 403, refused
        assert "You are not one of Heli Elsewhere&#x27;s pilots" in response.text
        # (refused before the question too)
        url = reverse("admin:fleet_vehicle_act", args=[elsewhere.pk])
        assert client.post(url, {"act": refused}).status_code == 403
    elsewhere.refresh_from_db()
    assert (elsewhere.status, elsewhere.command, elsewhere.pilot_on_duty) == (
        VehicleStatus.ACTIVE,
        "",
        None,
    )
    assert recorded.dispatcher.vehicles == [heli.pk], "only Heli One's worker is told"


def test_a_pilot_takes_an_rv_on_duty_and_hands_it_over_from_the_overview(
    client, pilot, heli, recorded
) -> None:
    second = heli.pilots.get(username="pilot-two")
    client.force_login(pilot)
    assert pilot_cell(client.get(OVERVIEW).text, "Heli One") == "none"

    taken = act(client, heli, "take_duty")
    assert taken.status_code == 302
    heli.refresh_from_db()
    assert heli.pilot_on_duty == pilot
    assert PilotDuty.objects.get(vehicle=heli, ended__isnull=True).pilot == pilot
    page = client.get(OVERVIEW).text
    assert "Heli One: pilot-one on duty (its pilot in command)" in page
    assert pilot_cell(page, "Heli One") == "pilot-one"
    assert buttons(page, "Heli One") == [
        "maintenance",
        "return",
        "return_home",
        "land",
        "hand_over",
    ]
    # A hand-over goes to nobody or to its other pilot, chosen beside the button.
    row = actions_row(page, "Heli One")
    choices = re.findall(r'<option value="(\d*)">([^<]+)</option>', row)
    assert choices == [("", "nobody"), (str(second.pk), "pilot-two")]

    # Without the page's dialog, the server asks first, naming whom it goes to.
    url = reverse("admin:fleet_vehicle_act", args=[heli.pk])
    asked = client.post(url, {"act": "hand_over", "to": str(second.pk)})
    assert asked.status_code == 200
    assert "Hand Heli One over to pilot-two? pilot-two becomes its pilot in command." in asked.text
    assert f'name="to" value="{second.pk}"' in asked.text
    assert Vehicle.objects.get(pk=heli.pk).pilot_on_duty == pilot, "nothing done yet"
    # Only to one of its pilots.
    stranger = member("pilot-three", PILOT)
    assert act(client, heli, "hand_over", to=str(stranger.pk)).status_code == 400

    assert act(client, heli, "hand_over", to=str(second.pk)).status_code == 302
    heli.refresh_from_db()
    assert heli.pilot_on_duty == second
    assert list(PilotDuty.objects.filter(vehicle=heli).values_list("pilot_name", "handed_to")) == [
        ("pilot-two", ""),
        ("pilot-one", "pilot-two"),
    ]
    # pilot-one is no longer on duty: no hand-over for them, and one they try is refused.
    page = client.get(OVERVIEW).text
    assert pilot_cell(page, "Heli One") == "pilot-two"
    assert "hand_over" not in buttons(page, "Heli One")
    refused = client.post(url, {"act": "hand_over", "confirmed": "yes"}, follow=True)
    assert "You are not on duty for Heli One." in refused.text
    assert Vehicle.objects.get(pk=heli.pk).pilot_on_duty == second

    # pilot-two hands it over to nobody.
    client.force_login(second)
    assert act(client, heli, "hand_over", to="").status_code == 302
    heli.refresh_from_db()
    assert heli.pilot_on_duty is None
    assert PilotDuty.objects.filter(ended__isnull=True).count() == 0


def test_a_fleet_manager_operates_any_rv_and_hands_over_for_a_pilot_who_left(
    client, pilot, heli, elsewhere, recorded
) -> None:
    vehicle_take_duty(vehicles=[heli], pilot=pilot, vvm=recorded)
    manager = member("manager", FLEET_MANAGER)
    client.force_login(manager)
    page = client.get(OVERVIEW).text
    assert buttons(page, "Heli Elsewhere") == ["maintenance", "return", "return_home", "land"]
    assert buttons(page, "Heli One")[-1] == "hand_over"  # (not one of its pilots: no duty)
    assert act(client, elsewhere, "maintenance").status_code == 302
    assert act(client, heli, "hand_over").status_code == 302
    heli.refresh_from_db()
    elsewhere.refresh_from_db()
    assert (heli.pilot_on_duty, elsewhere.status) == (None, VehicleStatus.MAINTENANCE)


def test_support_sees_the_overview_and_who_is_on_duty_with_no_actions(
    client, pilot, heli, recorded
) -> None:
    vehicle_take_duty(vehicles=[heli], pilot=pilot, vvm=recorded)
    client.force_login(member("helper", SUPPORT))
    page = client.get(OVERVIEW)
    assert page.status_code == 200
    assert pilot_cell(page.text, "Heli One") == "pilot-one"
    assert buttons(page.text, "Heli One") == []
    assert 'name="csrfmiddlewaretoken"' not in actions_row(page.text, "Heli One")
    for refused in ("land", "hand_over"):
        assert act(client, heli, refused).status_code == 403
    heli.refresh_from_db()
    assert (heli.command, heli.pilot_on_duty) == ("", pilot)
    # Nor do the vehicle list's bulk actions offer them anything.
    listed = client.get(reverse("admin:fleet_vehicle_changelist"))
    assert listed.status_code == 200 and "put_into_maintenance" not in listed.text
    bulk = {"action": "put_into_maintenance", "_selected_action": [heli.pk], "index": 0}
    client.post(reverse("admin:fleet_vehicle_changelist"), bulk)
    assert Vehicle.objects.get(pk=heli.pk).status == VehicleStatus.ACTIVE


def test_the_audit_log_entry_of_a_command_names_the_pilot_in_command(
    client, pilot, heli, recorded
) -> None:
    client.force_login(pilot)
    assert act(client, heli, "take_duty").status_code == 302
    assert act(client, heli, "return_home").status_code == 302
    entry = LogEntry.objects.get_for_object(heli).filter(action=LogEntry.Action.UPDATE).first()
    assert entry is not None and entry.actor == pilot
    assert entry.changes_dict["status"] == ["active", "maintenance"]  # (the command's)
    assert entry.additional_data == {"pilot_in_command": "pilot-one"}


def test_a_fleet_manager_assigns_pilots_among_the_pilot_group_and_superusers(
    client, pilot, staff, heli, recorded
) -> None:
    support = member("helper", SUPPORT)
    manager = member("manager", FLEET_MANAGER)
    vehicle_take_duty(vehicles=[heli], pilot=pilot, vvm=recorded)
    client.force_login(manager)
    url = reverse("admin:fleet_vehicle_change", args=[heli.pk])
    shown = client.get(url)
    assert shown.status_code == 200
    offered = set(shown.context["adminform"].form.fields["pilots"].queryset)
    assert offered == {pilot, heli.pilots.get(username="pilot-two"), staff}
    assert support not in offered and manager not in offered
    # Its pilot on duty is shown, not edited.
    assert "pilot_on_duty" not in shown.context["adminform"].form.fields
    assert "pilot-one" in shown.text

    response = client.post(url, form_as_shown(shown) | {"pilots": [pilot.pk]})
    assert response.status_code == 302, response.context["adminform"].form.errors
    assert list(heli.pilots.all()) == [pilot]
    assert Vehicle.objects.get(pk=heli.pk).pilot_on_duty == pilot
    refused = client.post(url, form_as_shown(shown) | {"pilots": [support.pk]})
    assert refused.status_code == 200 and list(heli.pilots.all()) == [pilot]


@pytest.mark.parametrize("model", ["pilotduty", "flight"])
def test_duties_and_flights_are_read_only_records(client, pilot, heli, recorded, model) -> None:
    vehicle_take_duty(vehicles=[heli], pilot=pilot, vvm=recorded)
    Flight.objects.create(
        vehicle=heli, started=timezone.now(), started_s=0.0, pilot=pilot, pilot_name="pilot-one"
    )
    record = PilotDuty.objects.get() if model == "pilotduty" else Flight.objects.get()
    for who in (pilot, member("helper", SUPPORT)):
        client.force_login(who)
        listed = client.get(reverse(f"admin:fleet_{model}_changelist"))
        assert listed.status_code == 200
        assert "Heli One" in listed.text and "pilot-one" in listed.text
        change = reverse(f"admin:fleet_{model}_change", args=[record.pk])
        assert client.get(change).status_code == 200
        assert client.post(change, {}).status_code == 403
        assert client.get(reverse(f"admin:fleet_{model}_add")).status_code == 403
        delete = reverse(f"admin:fleet_{model}_delete", args=[record.pk])
        assert client.post(delete, {"post": "yes"}).status_code == 403
    assert type(record).objects.count() == 1
