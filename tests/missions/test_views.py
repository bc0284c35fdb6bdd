"""Customer pages: one's own VVs only; another customer's VV is not found."""

from __future__ import annotations

import pytest
from django.urls import reverse

from vvm_worker.services import vv_submit


@pytest.fixture
def vv_a(customer_a, ground_station, vvm_factory):
    return vv_submit(customer=customer_a, name="Alpha VV", program="var a = 1;", vvm=vvm_factory())


@pytest.fixture
def vv_b(customer_b, ground_station, vvm_factory):
    return vv_submit(customer=customer_b, name="Bravo VV", program="var b = 1;", vvm=vvm_factory())


def test_pages_need_a_login(client, vv_a) -> None:
    response = client.get(reverse("home"))
    assert response.status_code == 302 and response["Location"].startswith("/accounts/login/")


def test_login_page_loads(client, db) -> None:
    response = client.get("/accounts/login/")
    assert response.status_code == 200
    assert 'name="username"' in response.text and 'name="password"' in response.text


def test_a_customer_sees_only_its_own_vvs(client, user_a, vv_a, vv_b) -> None:
    client.force_login(user_a)
    page = client.get(reverse("home")).text
    assert "Alpha VV" in page and "Bravo VV" not in page
    assert client.get(reverse("vv-detail", args=[vv_a.pk])).status_code == 200


def test_another_customers_vv_is_not_found(client, user_a, vv_b) -> None:
    client.force_login(user_a)
    assert client.get(reverse("vv-detail", args=[vv_b.pk])).status_code == 404


def test_staff_see_every_vv(client, staff, vv_a, vv_b) -> None:
    client.force_login(staff)
    page = client.get(reverse("home")).text
    assert "Alpha VV" in page and "Bravo VV" in page
