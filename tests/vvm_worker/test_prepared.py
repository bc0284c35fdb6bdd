"""A read compiled once gives what its queryset gives, for any key, with its related rows."""

from __future__ import annotations

import uuid

import pytest
from django.db import transaction

from missions.models import VirtualVehicle
from tests.factories import CustomerFactory, GroundStationFactory, VehicleFactory
from vvm_worker.services.prepared import PreparedRead

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

    read = PreparedRead(build, sample=uuid.UUID(int=0))
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
