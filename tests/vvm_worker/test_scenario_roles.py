"""Scenarios with teams (issue 57): customers' users with roles, staff in their groups, the
pilots of each vehicle; parsed (pure), loaded by ``loadscenario`` (idempotent), and the
demo's viewer and pilot (``demo_people``; tests/vvm_worker/test_demo.py sees their logins)."""

from __future__ import annotations

import copy
import json
import re
from pathlib import Path
from typing import Any

import pytest
from django.core.management import CommandError, call_command

from accounts import roles
from accounts.models import Customer, User
from fleet.models import Vehicle
from tests.conftest import SCENARIOS
from tests.factories import UserFactory
from vvm_worker import scenario as scenario_module
from vvm_worker.scenario import (
    MemberSpec,
    ScenarioError,
    StaffSpec,
    load_scenario,
    parse_scenario,
)
from vvm_worker.services.scenarios import demo_people, scenario_apply

SQUARE = [[48.0, 12.0], [48.0, 12.01], [48.01, 12.01], [48.01, 12.0], [48.0, 12.0]]


def _vehicle(name: str, **extra: Any) -> dict[str, Any]:
    return {
        "name": name,
        "depot": [48.005, 12.005, 0],
        "area": copy.deepcopy(SQUARE),
        "min_altitude_m": 0,
        "max_altitude_m": 120,
        "max_speed_mps": 10,
        "sensors": ["Thermometer"],
        **extra,
    }


def team(**changes: Any) -> dict[str, Any]:
    """A scenario with a team: Customer A's developer and viewer, a user without a role,
    two staff users, pilots on one RV; ``changes`` replace top-level keys."""
    data: dict[str, Any] = {
        "name": "Team",
        "ground_stations": [{"name": "GS Base", "position": [48.0, 12.0, 0]}],
        "vehicles": [_vehicle("Heli One", pilots=["pia", "fred"]), _vehicle("Heli Two")],
        "customers": [
            {
                "name": "Customer A",
                "max_parallel_vvs": 2,
                "users": [
                    {"name": "dev", "role": "developer", "email": "dev@example.org"},
                    {"name": "vera", "role": "viewer"},
                    {"name": "olga"},
                ],
            },
            {"name": "Customer B", "max_parallel_vvs": 1},
        ],
        "staff": [
            {"name": "pia", "groups": ["pilot"]},
            {"name": "fred", "groups": ["fleet manager", "pilot"], "email": "fred@example.org"},
        ],
        "vvs": [],
    }
    data.update(changes)
    return data


def parse(data: Any) -> Any:
    return parse_scenario(data, base_dir=Path("/nonexistent"))


def refused(data: Any, message: str) -> ScenarioError:
    """The parser refuses ``data`` with exactly ``message`` (place: what)."""
    with pytest.raises(ScenarioError) as caught:
        parse(data)
    assert str(caught.value) == message
    return caught.value


# --- parsing (no database) ---------------------------------------------------------------------


def test_roles_groups_and_pilots_are_parsed_and_a_user_without_a_role_is_an_owner() -> None:
    scenario = parse(team())
    a, b = scenario.customers
    assert a.users == (
        MemberSpec(name="dev", role="developer", email="dev@example.org"),
        MemberSpec(name="vera", role="viewer"),
        MemberSpec(name="olga", role="owner"),
    )
    assert b.users == ()
    assert scenario.staff == (
        StaffSpec(name="pia", groups=("pilot",)),
        StaffSpec(name="fred", groups=("fleet manager", "pilot"), email="fred@example.org"),
    )
    assert scenario.vehicles[0].pilots == ("pia", "fred")
    assert scenario.vehicles[1].pilots is None  # said nothing: pilots given elsewhere stay
    assert scenario.outside_pilots == ()


def test_the_scenario_files_of_before_mean_the_same() -> None:
    for path in sorted(SCENARIOS.glob("*.json")):
        scenario = load_scenario(path)
        assert scenario.staff == ()
        assert all(c.users == () for c in scenario.customers)
        assert all(v.pilots is None for v in scenario.vehicles)


def test_the_parsers_names_are_those_of_accounts_roles() -> None:
    """A pure core imports no app: its copies of the names must agree with the models'."""
    assert set(scenario_module.MEMBER_ROLES) == set(roles.CUSTOMER_ROLES)
    assert scenario_module.DEFAULT_ROLE == roles.OWNER
    assert scenario_module.STAFF_GROUPS == roles.STAFF_GROUPS


def test_a_pilot_the_scenario_does_not_name_is_left_to_the_database() -> None:
    data = team()
    data["vehicles"][1]["pilots"] = ["zoe"]
    data["events"] = [
        {"at_s": 50, "add_vehicle": _vehicle("Heli Three", pilots=["pia", "max"])},
        {"at_s": 10, "vehicle": "Heli Two", "action": "maintenance"},
    ]
    scenario = parse(data)
    # Places in the file, as it is written (events are sorted by time after parsing).
    assert scenario.outside_pilots == (
        ("vehicles[1].pilots[0]", "zoe"),
        ("events[0].add_vehicle.pilots[1]", "max"),
    )


def _with(path: str, value: Any) -> dict[str, Any]:
    data = team()
    *parents, last = [int(p) if p.isdigit() else p for p in path.split(".")]
    target: Any = data
    for part in parents:
        target = target[part]
    target[last] = value
    return data


@pytest.mark.parametrize(
    ("path", "value", "message"),
    [
        (
            "customers.0.users.1.role",
            "admin",
            "customers[0].users[1].role: unknown role 'admin' (one of: owner, developer, viewer)",
        ),
        (
            "customers.0.users.1.role",
            None,
            "customers[0].users[1].role: must be a string, got null",
        ),
        (
            "customers.0.users.1",
            {"name": "vera", "roles": ["viewer"]},
            "customers[0].users[1]: unknown key 'roles' (allowed: email, name, role)",
        ),
        (
            "customers.0.users.1",
            {"role": "viewer"},
            "customers[0].users[1]: missing required key 'name'",
        ),
        (
            "customers.0.users.1.name",
            "vera smith",
            "customers[0].users[1].name: 'vera smith' is not a user name: letters, digits and "
            "@ . + - _ only, at most 150 characters",
        ),
        (
            "customers.0.users.0.email",
            "dev.example.org",
            "customers[0].users[0].email: 'dev.example.org' is not an e-mail address",
        ),
        ("customers.1.users", {}, "customers[1].users: must be an array, got an object"),
        (
            "staff.1.groups.0",
            "fleet managers",
            "staff[1].groups[0]: unknown staff group 'fleet managers' "
            "(one of: fleet manager, pilot, support)",
        ),
        (
            "staff.1.groups",
            ["pilot", "pilot"],
            "staff[1].groups[1]: 'pilot' is given twice (also at staff[1].groups[0])",
        ),
        ("staff.0.groups", "pilot", "staff[0].groups: must be an array, got a string"),
        (
            "staff.0",
            {"name": "pia", "role": "pilot"},
            "staff[0]: unknown key 'role' (allowed: email, groups, name)",
        ),
        ("staff", {"pia": ["pilot"]}, "staff: must be an array, got an object"),
        (
            "vehicles.0.pilots",
            ["pia", "pia"],
            "vehicles[0].pilots[1]: 'pia' is given twice (also at vehicles[0].pilots[0])",
        ),
        ("vehicles.0.pilots", "pia", "vehicles[0].pilots: must be an array, got a string"),
        (
            "vehicles.0.pilots",
            ["pia", "vera"],
            "vehicles[0].pilots[1]: 'vera' is a customer's user (customers[0].users[1]); a pilot "
            "is staff (list them in staff, with the group 'pilot')",
        ),
        (
            "staff.1.name",
            "dev",
            "staff[1].name: duplicate user name 'dev' (also at customers[0].users[0].name)",
        ),
        (
            "customers.1.users",
            [{"name": "vera"}],
            "customers[1].users[0].name: duplicate user name 'vera' "
            "(also at customers[0].users[1].name)",
        ),
    ],
)
def test_bad_teams_are_refused_saying_what_and_where(path: str, value: Any, message: str) -> None:
    refused(_with(path, value), message)


def test_an_error_in_a_file_names_the_file(tmp_path: Path) -> None:
    bad = tmp_path / "team.json"
    bad.write_text(json.dumps(_with("staff.0.groups", ["pilot", "driver"])))
    with pytest.raises(ScenarioError) as caught:
        load_scenario(bad)
    assert str(caught.value) == (
        f"{bad}: staff[0].groups[1]: unknown staff group 'driver' "
        "(one of: fleet manager, pilot, support)"
    )


# --- loading -----------------------------------------------------------------------------------


def _file(tmp_path: Path, data: dict[str, Any]) -> str:
    path = tmp_path / "team.json"
    path.write_text(json.dumps(data))
    return str(path)


@pytest.mark.django_db
def test_loadscenario_makes_members_with_roles_staff_in_groups_and_pilots(
    tmp_path: Path, settings, capsys
) -> None:
    settings.CPCC_SCENARIO_PASSWORD = "team-pass-1"
    path = _file(tmp_path, team())
    call_command("loadscenario", path)
    first = capsys.readouterr().out
    call_command("loadscenario", path)  # idempotent: the same people, roles and pilots
    assert capsys.readouterr().out == first
    for line in (
        "  login customer-a / team-pass-1\n",
        "  login dev / team-pass-1  (Customer A, developer)\n",
        "  login vera / team-pass-1  (Customer A, viewer)\n",
        "  login olga / team-pass-1  (Customer A, owner)\n",
        "  login customer-b / team-pass-1\n",
        "  login pia / team-pass-1  (staff: pilot)\n",
        "  login fred / team-pass-1  (staff: fleet manager, pilot)\n",
    ):
        assert line in first

    a = Customer.objects.get(name="Customer A")
    members = {u.username: u for u in User.objects.filter(customer=a)}
    assert {name: u.role for name, u in members.items()} == {
        "customer-a": "owner",  # every customer's own login, its owner, as before
        "dev": "developer",
        "vera": "viewer",
        "olga": "owner",
    }
    assert members["dev"].email == "dev@example.org"
    assert all(u.check_password("team-pass-1") for u in members.values())
    assert not any(u.is_staff for u in members.values())

    pia, fred = User.objects.get(username="pia"), User.objects.get(username="fred")
    for user, groups in ((pia, ["pilot"]), (fred, ["fleet manager", "pilot"])):
        assert user.is_staff and not user.is_superuser and user.customer is None
        assert sorted(user.groups.values_list("name", flat=True)) == groups
        assert user.check_password("team-pass-1")
    assert pia.has_perm("fleet.operate_vehicle") and not pia.has_perm("fleet.change_vehicle")
    assert fred.has_perm("fleet.change_vehicle")

    one, two = Vehicle.objects.get(name="Heli One"), Vehicle.objects.get(name="Heli Two")
    assert sorted(one.pilots.values_list("username", flat=True)) == ["fred", "pia"]
    assert one.pilot_on_duty is None  # assigned, not on duty
    assert not two.pilots.exists()
    assert User.objects.count() == 7


@pytest.mark.django_db
def test_a_scenario_that_leaves_pilots_out_keeps_those_an_administrator_gave(tmp_path) -> None:
    scenario = parse(team())
    scenario_apply(scenario=scenario, logins=False)
    two = Vehicle.objects.get(name="Heli Two")
    two.pilots.add(User.objects.get(username="pia"))
    scenario_apply(scenario=scenario, logins=False)
    assert list(two.pilots.values_list("username", flat=True)) == ["pia"]
    # A scenario that names them decides: here, nobody but fred.
    data = team()
    data["vehicles"][0]["pilots"] = ["fred"]
    scenario_apply(scenario=parse(data), logins=False)
    assert list(Vehicle.objects.get(name="Heli One").pilots.values_list("username", flat=True)) == [
        "fred"
    ]


@pytest.mark.django_db
def test_without_logins_the_team_is_made_with_no_usable_password() -> None:
    """``simulate``: nobody logs in, but the roles and pilots are there (and no time goes into
    hashing passwords)."""
    loaded = scenario_apply(scenario=parse(team()), logins=False)
    assert loaded.logins == []
    assert not User.objects.filter(username="customer-a").exists()
    vera = User.objects.get(username="vera")
    assert vera.role == "viewer" and not vera.has_usable_password()
    assert not User.objects.get(username="pia").has_usable_password()
    assert Vehicle.objects.get(name="Heli One").pilots.count() == 2


@pytest.mark.django_db
def test_a_pilot_may_be_staff_of_the_database(tmp_path: Path) -> None:
    UserFactory(username="zoe", is_staff=True)
    data = team()
    data["vehicles"][1]["pilots"] = ["zoe"]
    scenario_apply(scenario=parse(data), logins=False)
    assert list(Vehicle.objects.get(name="Heli Two").pilots.values_list("username", flat=True)) == [
        "zoe"
    ]


@pytest.mark.django_db
@pytest.mark.parametrize("who", ["nobody", "a customer's user"])
def test_a_pilot_who_is_not_staff_is_refused_naming_the_place(tmp_path: Path, who: str) -> None:
    if who != "nobody":
        UserFactory(username="zoe", customer=Customer.objects.create(name="Z", slug="z"))
    data = team()
    data["vehicles"][1]["pilots"] = ["zoe"]
    with pytest.raises(CommandError) as caught:
        call_command("loadscenario", _file(tmp_path, data), "--no-vvs")
    assert str(caught.value) == (
        f"scenario error: {tmp_path / 'team.json'}: vehicles[1].pilots[0]: no staff user 'zoe': "
        "a pilot is one of the scenario's staff or a staff user in the database"
    )
    assert not Vehicle.objects.exists()  # nothing loaded


@pytest.mark.django_db
@pytest.mark.parametrize(
    ("change", "place", "message"),
    [
        (
            ("customers.0.users.1.name", "customer-b"),
            "customers[0].users[1].name",
            "'customer-b' is the login of customer 'Customer B' (customers[1]), which every "
            "customer gets as its owner: choose another name",
        ),
        (
            ("customers.0.users.1.name", "bob"),
            "customers[0].users[1].name",
            "'bob' is a user of customer 'Customer C' in the database, so it cannot be a user "
            "of customer 'Customer A': choose another name",
        ),
        (
            ("customers.0.users.1.name", "operator"),
            "customers[0].users[1].name",
            "'operator' is staff in the database, so it cannot be a user of customer "
            "'Customer A': choose another name",
        ),
        (
            ("staff.0.name", "bob"),
            "staff[0].name",
            "'bob' is a user of customer 'Customer C' in the database, so it cannot be staff: "
            "choose another name",
        ),
        (
            ("customers.0.users.0.email", "dev@"),
            "customers[0].users[0].email",
            "'dev@' is not an e-mail address",
        ),
    ],
)
def test_a_name_that_is_someone_else_in_the_database_is_refused(
    staff, change: tuple[str, Any], place: str, message: str
) -> None:
    UserFactory(username="bob", customer=Customer.objects.create(name="Customer C", slug="c"))
    data = _with(*change)
    if change[0] == "staff.0.name":
        data["vehicles"][0]["pilots"] = ["bob", "fred"]
    with pytest.raises(ScenarioError) as caught:
        scenario_apply(scenario=parse(data), logins=False)
    assert (caught.value.path, caught.value.message) == (place, message)
    assert not Vehicle.objects.exists()
    assert User.objects.get(username="bob").customer.name == "Customer C"


@pytest.mark.django_db
def test_the_examples_load_as_before(settings, capsys) -> None:
    """No team in a scenario: the customers' logins as before, nobody else."""
    settings.CPCC_SCENARIO_PASSWORD = "paper-pass-1"
    call_command("loadscenario", str(SCENARIOS / "paper-fig3.json"), "--no-vvs")
    out = capsys.readouterr().out
    assert re.findall(r"^  login .*$", out, re.MULTILINE) == [
        f"  login customer-{x} / paper-pass-1" for x in "abc"
    ]
    assert sorted(User.objects.values_list("username", "role")) == [
        (f"customer-{x}", "owner") for x in "abc"
    ]


# --- the demo's people -------------------------------------------------------------------------


@pytest.mark.django_db
def test_the_demos_viewer_reads_and_its_pilot_may_fly_every_rv_off_duty(settings) -> None:
    loaded = scenario_apply(scenario=load_scenario(SCENARIOS / "paper-fig3.json"), logins=False)
    customer = loaded.customers["Customer A"]
    for _ in range(2):  # every demo run: the same two, nothing more
        viewer, pilot = demo_people(
            customer=customer, vehicles=list(loaded.vehicles.values()), password="demo-pass-1"
        )
    assert viewer is not None
    assert (viewer.username, viewer.customer, viewer.role) == (
        "customer-a-viewer",
        customer,
        "viewer",
    )
    assert not viewer.is_staff and viewer.check_password("demo-pass-1")
    assert pilot.username == "pilot" and pilot.is_staff and not pilot.is_superuser
    assert list(pilot.groups.values_list("name", flat=True)) == ["pilot"]
    assert pilot.check_password("demo-pass-1")
    for vehicle in Vehicle.objects.all():
        assert list(vehicle.pilots.all()) == [pilot]
        assert vehicle.pilot_on_duty is None
    assert User.objects.count() == 2


@pytest.mark.django_db
def test_user_set_login_gives_a_role_or_staff_groups_and_refuses_others(customer_a) -> None:
    from vvm_worker.services import user_set_login

    dev = user_set_login(username="dev", password="p-1", customer=customer_a, role="developer")
    assert (dev.customer, dev.role, dev.is_staff) == (customer_a, "developer", False)
    assert user_set_login(username="dev", password="p-2").role == "developer"  # kept
    sam = user_set_login(username="sam", password="p-1", groups=["support"])
    assert sam.is_staff and not sam.is_superuser
    assert list(sam.groups.values_list("name", flat=True)) == ["support"]
    with pytest.raises(ValueError, match="'boss' is not a role"):
        user_set_login(username="x", password="p-1", customer=customer_a, role="boss")
    with pytest.raises(ValueError, match="not staff groups: pilots"):
        user_set_login(username="x", password="p-1", groups=["pilots"])
    assert not User.objects.filter(username="x").exists()
