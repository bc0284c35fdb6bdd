"""Customers, their users and quotas."""

from __future__ import annotations

import pytest
from django.db import IntegrityError

from accounts.models import DEFAULT_MAX_QUEUED_VVS, Customer
from accounts.selectors import customer_catalog
from fleet.models import SensorType
from vvm_worker.services import customer_limits


@pytest.mark.django_db
def test_customer_gets_a_slug_from_its_name() -> None:
    assert Customer.objects.create(name="Customer A").slug == "customer-a"


@pytest.mark.django_db
def test_customer_names_are_unique() -> None:
    Customer.objects.create(name="Acme")
    with pytest.raises(IntegrityError):
        Customer.objects.create(name="Acme", slug="acme-2")


@pytest.mark.django_db
def test_parallel_vv_quota_must_be_positive() -> None:
    with pytest.raises(IntegrityError):
        Customer.objects.create(name="Zero", max_parallel_vvs=0)


@pytest.mark.django_db
def test_queued_vv_quota_has_a_default_and_must_be_positive() -> None:
    assert Customer.objects.create(name="Default").max_queued_vvs == DEFAULT_MAX_QUEUED_VVS == 100
    with pytest.raises(IntegrityError):
        Customer.objects.create(name="Zero", max_queued_vvs=0)


def test_a_user_belongs_to_one_customer(user_a, customer_a, customer_b) -> None:
    assert user_a.customer == customer_a
    assert list(customer_a.users.all()) == [user_a]
    assert list(customer_b.users.all()) == []


def test_catalog_hides_privileged_entries_from_ordinary_customers(customer_a) -> None:
    names = [e["name"] for e in customer_catalog(customer=customer_a)]
    assert "Battery" not in names
    assert {"CO2", "GPS", "Thermometer", "Camera 640x480"} <= set(names)
    customer_a.privileged = True
    customer_a.save()
    assert "Battery" in [e["name"] for e in customer_catalog(customer=customer_a)]


def test_catalog_can_be_limited_per_customer(customer_a, customer_b) -> None:
    customer_a.allowed_sensors.set(SensorType.objects.filter(name__in=["GPS", "CO2"]))
    assert [e["name"] for e in customer_catalog(customer=customer_a)] == ["CO2", "GPS"]
    assert len(customer_catalog(customer=customer_b)) == 9  # everything but Battery


def test_quotas_become_runtime_limits(customer_a) -> None:
    customer_a.cpu_ms_per_step = 500
    customer_a.heap_bytes = 32 * 1024 * 1024
    customer_a.storage_bytes = 1000
    customer_a.max_tasks_per_vv = 7
    customer_a.allowed_api_calls = ["task.execute", "storage.store"]
    limits = customer_limits(customer=customer_a)
    assert limits.cpu_s == 0.5
    assert limits.heap_bytes == 32 * 1024 * 1024
    assert limits.storage_bytes == 1000
    assert limits.max_tasks == 7
    assert limits.allowed_calls == frozenset({"task.execute", "storage.store"})
