"""Staff put customers in service classes, in the admin and over the API
(/api/v1/service-classes/, ``service_class`` of /api/v1/customers/); customers cannot."""

from __future__ import annotations

import pytest
from django.urls import reverse

from accounts.models import ServiceClass
from tests.admin_forms import form_as_shown
from vvm_worker.services.customers import service_class_save

pytestmark = pytest.mark.django_db


def test_staff_add_a_class_and_put_a_customer_in_it(client, staff, customer_a, customer_b) -> None:
    client.force_login(staff)
    added = client.post(
        reverse("admin:accounts_serviceclass_add"),
        {"name": "premium", "p95_s": "30", "weight": "2"},
    )
    assert added.status_code == 302, added.content
    premium = ServiceClass.objects.get(name="premium")
    assert (premium.p95_s, premium.weight) == (30.0, 2.0)
    url = reverse("admin:accounts_customer_change", args=[customer_a.pk])
    shown = client.get(url)
    assert 'name="service_class"' in shown.text
    saved = client.post(url, form_as_shown(shown) | {"service_class": premium.pk})
    assert saved.status_code == 302, saved.content
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert customer_a.service_class == premium and customer_b.service_class is None
    # The lists show it: the customer's class, the class's customers.
    customers = client.get(reverse("admin:accounts_customer_changelist")).text
    assert "premium" in customers
    only_premium = client.get(
        reverse("admin:accounts_customer_changelist"), {"service_class__id__exact": premium.pk}
    ).text
    assert "Customer A" in only_premium and "Customer B" not in only_premium
    classes = client.get(reverse("admin:accounts_serviceclass_changelist")).text
    assert '<td class="field-customer_count">1</td>' in classes


def test_the_admin_refuses_a_bad_target_and_keeps_a_class_name(client, staff) -> None:
    client.force_login(staff)
    refused = client.post(
        reverse("admin:accounts_serviceclass_add"), {"name": "x", "p95_s": "0", "weight": "1"}
    )
    assert refused.status_code == 200 and "p95_s" in refused.text
    assert not ServiceClass.objects.exists()
    gold = service_class_save(name="gold", p95_s=60.0)
    change = reverse("admin:accounts_serviceclass_change", args=[gold.pk])
    changed = client.post(change, {"name": "platinum", "p95_s": "45", "weight": "1.5"})
    assert changed.status_code == 302, changed.content
    gold.refresh_from_db()
    assert (gold.name, gold.p95_s, gold.weight) == ("gold", 45.0, 1.5)


def test_customers_see_no_class_admin(client, user_a) -> None:
    client.force_login(user_a)
    response = client.get(reverse("admin:accounts_serviceclass_changelist"))
    assert response.status_code == 302  # to the admin's login


# --- the API -------------------------------------------------------------------------------------


def test_staff_save_classes_and_set_a_customers_class_over_the_api(
    api_staff, customer_a, customer_b
) -> None:
    created = api_staff.post(
        "/api/v1/service-classes/", {"name": "premium", "p95_s": 30}, format="json"
    )
    assert created.status_code == 201, created.content
    assert created.json() | {"id": 0} == {
        "id": 0,
        "name": "premium",
        "p95_s": 30.0,
        "weight": 1.0,
        "customers": 0,
    }
    changed = api_staff.post(
        "/api/v1/service-classes/", {"name": "premium", "p95_s": 25, "weight": 2}, format="json"
    )
    assert changed.status_code == 200 and changed.json()["p95_s"] == 25.0
    url = f"/api/v1/customers/{customer_a.pk}/"
    put_in = api_staff.patch(url, {"service_class": "premium"}, format="json")
    assert put_in.status_code == 200, put_in.content
    assert put_in.json()["service_class"] == {"name": "premium", "p95_s": 25.0, "weight": 2.0}
    other = api_staff.get(f"/api/v1/customers/{customer_b.pk}/").json()
    assert other["service_class"] is None
    (listed,) = api_staff.get("/api/v1/service-classes/").json()["results"]
    assert listed["customers"] == 1
    taken_out = api_staff.patch(url, {"service_class": None}, format="json")
    assert taken_out.json()["service_class"] is None
    customer_a.refresh_from_db()
    assert customer_a.service_class is None


def test_bad_class_input_is_refused_naming_the_field(api_staff, customer_a) -> None:
    cases = [
        ({"name": "x", "p95_s": 0}, "p95_s"),
        ({"name": "x", "p95_s": "30"}, "p95_s"),
        ({"name": "x", "p95_s": 30, "weight": 0}, "weight"),
        ({"p95_s": 30}, "name"),
    ]
    for data, field in cases:
        response = api_staff.post("/api/v1/service-classes/", data, format="json")
        assert response.status_code == 400, (data, response.content)
        assert field in response.json(), (data, response.json())
    unknown = api_staff.patch(
        f"/api/v1/customers/{customer_a.pk}/", {"service_class": "gold"}, format="json"
    )
    assert unknown.status_code == 400
    assert "no service class named 'gold'" in unknown.json()["service_class"][0]


def test_customers_cannot_see_or_change_classes(api_a, api_staff, customer_a) -> None:
    service_class_save(name="premium", p95_s=30.0)
    for response in [
        api_a.get("/api/v1/service-classes/"),
        api_a.post("/api/v1/service-classes/", {"name": "mine", "p95_s": 1}, format="json"),
        api_a.patch(
            f"/api/v1/customers/{customer_a.pk}/", {"service_class": "premium"}, format="json"
        ),
    ]:
        assert response.status_code == 403
        assert "Only platform staff" in response.json()["detail"]
    assert list(ServiceClass.objects.values_list("name", flat=True)) == ["premium"]
    customer_a.refresh_from_db()
    assert customer_a.service_class is None
