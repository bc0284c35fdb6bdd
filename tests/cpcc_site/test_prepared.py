"""A read compiled once gives what its queryset gives, for any key, with its related rows."""

from __future__ import annotations

import uuid

import pytest
from django.db import DatabaseError, transaction

from cpcc_site.prepared import PreparedRead, save_fields
from missions.models import VirtualVehicle
from tests.factories import CustomerFactory, GroundStationFactory, VehicleFactory

pytestmark = pytest.mark.django_db


def _vv(**hosts) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=CustomerFactory(),
        name="VV",
        program="VV.log('x')",
        seed=7,
        start_ms=0,
        catalog=[{"name": "CO2", "kind": "scalar", "unit": "ppm", "params": {"a": [1, 2]}}],
        pending={"q": 3, "kind": "single", "tasks": []},
        submitted_s=1.5,
        **hosts,
    )


def test_it_reads_each_key_as_the_queryset_does_with_its_related_rows() -> None:
    def build(key):
        return (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .select_related("customer", "host_gs", "host_rv")
            .filter(pk=key)
        )

    read = PreparedRead(build, samples=[("pk", uuid.UUID(int=0))])
    on_rv = _vv(host_rv=VehicleFactory(name="Heli One"))
    on_gs = _vv(host_gs=GroundStationFactory(name="GS One"))
    with transaction.atomic():
        for vv in (on_rv, on_gs, on_rv):
            got = read.first(vv.pk)
            want = build(vv.pk).get()
            assert got is not None and got.pk == vv.pk
            for field in VirtualVehicle._meta.concrete_fields:
                assert getattr(got, field.attname) == getattr(want, field.attname), field.name
            assert got.customer.name == want.customer.name
            assert (got.host_rv and got.host_rv.name) == (want.host_rv and want.host_rv.name)
            assert (got.host_gs and got.host_gs.name) == (want.host_gs and want.host_gs.name)
        assert read.first(uuid.uuid4()) is None


def test_several_keys_each_in_its_place_another_customers_row_is_not_read() -> None:
    def build(key, customer):
        return (
            VirtualVehicle.objects.select_related("customer", "host_gs", "host_rv")
            .filter(pk=key, customer_id=customer)
            .order_by()
        )

    read = PreparedRead(build, samples=[("pk", uuid.UUID(int=0)), ("customer_id", -1)])
    mine, theirs = _vv(), _vv()
    got = read.first(mine.pk, mine.customer_id)
    assert got == build(mine.pk, mine.customer_id).get()
    assert got is not None and got.customer.name == mine.customer.name
    assert read.first(theirs.pk, mine.customer_id) is None
    assert read.first(mine.pk, theirs.customer_id) is None
    assert read.first(theirs.pk, theirs.customer_id) == theirs


def test_a_sample_the_query_holds_twice_is_refused() -> None:
    read = PreparedRead(
        lambda key: VirtualVehicle.objects.filter(pk=key) | VirtualVehicle.objects.filter(pk=key),
        samples=[("pk", uuid.UUID(int=0))],
    )
    with pytest.raises(ValueError, match="must appear once"):
        read.first(uuid.uuid4())


def test_save_fields_writes_those_fields_as_save_does_and_leaves_the_others() -> None:
    vv = _vv(host_rv=VehicleFactory(name="Heli One"))
    other = _vv()
    stale = VirtualVehicle.objects.get(pk=vv.pk)
    stale.name = "changed elsewhere"  # not among the fields: not written
    stale.host_rv = None
    stale.host_gs = GroundStationFactory(name="GS One")
    stale.pending = {"q": 4, "kind": "single", "tasks": [{"lat": 1.5}]}
    stale.steps = 9
    before = vv.updated
    save_fields(stale, ["host_rv", "host_gs", "pending", "steps", "updated"])
    got = VirtualVehicle.objects.get(pk=vv.pk)
    assert (got.host_rv_id, got.host_gs_id) == (None, stale.host_gs.pk)
    assert got.pending == {"q": 4, "kind": "single", "tasks": [{"lat": 1.5}]}
    assert got.steps == 9 and got.name == "VV"
    assert got.updated > before  # auto_now sets itself, as in save
    assert VirtualVehicle.objects.get(pk=other.pk).steps == other.steps
    stale.delete()
    with pytest.raises(DatabaseError, match="no row to update"):
        save_fields(stale, ["steps"])
