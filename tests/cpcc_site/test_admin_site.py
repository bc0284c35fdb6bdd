"""The admin site (cpcc_site/admin_site.py): the platform's own sections before the libraries',
and a list with nothing in it says what its things are for and how to add one."""

from __future__ import annotations

import html

import pytest
from django.urls import reverse

from accounts.models import ServiceClass
from fleet.models import NoFlyZone
from tests.factories import AREA_ONE

pytestmark = pytest.mark.django_db

PLATFORM = ["fleet", "missions", "accounts"]


def _labels(apps: list[dict]) -> list[str]:
    return [app["app_label"] for app in apps]


def test_the_index_and_the_side_bar_list_the_platforms_apps_first(client, staff) -> None:
    client.force_login(staff)
    index = client.get(reverse("admin:index"))
    labels = _labels(index.context["app_list"])
    assert labels[:3] == PLATFORM
    assert {"axes", "authtoken", "auth", "auditlog"} <= set(labels[3:])
    # The libraries' sections in the admin's own order (by name) after them.
    names = [app["name"].lower() for app in index.context["app_list"][3:]]
    assert names == sorted(names)
    page = html.unescape(index.text)
    assert page.index(">Fleet<") < page.index(">Customers and users<") < page.index(">Axes<")

    listed = client.get(reverse("admin:fleet_vehicle_changelist"))
    assert _labels(listed.context["available_apps"])[:3] == PLATFORM, "the side bar too"


EMPTY = {
    "accounts_serviceclass": "A service class is a level of service promised to customers",
    "fleet_noflyzone": "A no-fly zone is an area no RV flies into",
}


ADD_ONE = {
    "accounts_serviceclass": lambda: ServiceClass.objects.create(name="premium", p95_s=30),
    "fleet_noflyzone": lambda: NoFlyZone.objects.create(
        name="Prison", area=[list(p) for p in AREA_ONE]
    ),
}


@pytest.mark.parametrize("model", sorted(EMPTY))
def test_an_empty_list_says_what_its_things_are_for_and_how_to_add_one(
    client, staff, model
) -> None:
    client.force_login(staff)
    url = reverse(f"admin:{model}_changelist")
    page = html.unescape(client.get(url).text)
    assert EMPTY[model] in page
    add = reverse(f"admin:{model}_add")
    assert f'<a href="{add}" class="addlink">' in page.split('id="cpcc-empty-list"')[1]

    ADD_ONE[model]()
    page = html.unescape(client.get(url).text)
    assert EMPTY[model] not in page and 'id="cpcc-empty-list"' not in page
    searched = html.unescape(client.get(url, {"q": "nothing like it"}).text)
    assert "0 results" in searched and EMPTY[model] not in searched, "found none, not none"


def test_a_list_of_what_only_the_platform_makes_offers_no_add(client, staff) -> None:
    client.force_login(staff)
    page = html.unescape(client.get(reverse("admin:missions_task_changelist")).text)
    empty = page.split('id="cpcc-empty-list"')[1]
    assert "when a VV asks for a reading" in empty and "addlink" not in empty
