"""The dry run's service: the copy of the fleet it flies, and dry runs side by side."""

from __future__ import annotations

import json
import threading
from pathlib import Path

import pytest
from django.db import connection

from fleet.models import NoFlyZone, VehicleStatus
from tests.factories import AREA_TWO, VehicleFactory
from vvm_worker.scenario import parse_scenario
from vvm_worker.services.dry_run import COPY_CUSTOMER, DryRunReport, fleet_copy, vv_dry_run_for_user


def test_the_copy_holds_the_fleet_in_service_and_names_nothing(ground_station, heli_one) -> None:
    VehicleFactory(name="Heli Two", area=AREA_TWO, max_speed_mps=4.0, battery_s=900.0)
    VehicleFactory(name="Heli Resting", status=VehicleStatus.MAINTENANCE)
    VehicleFactory(name="Heli Gone", status=VehicleStatus.REMOVED)
    VehicleFactory(name="Heli Bare", sensors=[])  # it could serve nothing
    NoFlyZone.objects.create(
        name="Airfield", area=[[48.11, 12.86], [48.11, 12.861], [48.111, 12.861], [48.11, 12.86]]
    )
    document = fleet_copy(name="survey", program="VV.log(1);")
    text = json.dumps(document)
    for name in ("Heli", "GS Base", "Airfield"):
        assert name not in text, f"the copy names {name!r}"
    scenario = parse_scenario(document, base_dir=Path())
    assert [v.name for v in scenario.vehicles] == ["RV 1", "RV 2"]
    two = scenario.vehicles[1]
    assert two.area == tuple(tuple(p) for p in AREA_TWO)
    assert (two.max_speed_mps, two.battery_s) == (4.0, 900.0)
    assert [gs.name for gs in scenario.ground_stations] == ["GS 1"]
    assert [z.name for z in scenario.no_fly_zones] == ["zone 1"]
    (vv,) = scenario.vvs
    assert (vv.customer, vv.name, vv.source) == (COPY_CUSTOMER, "survey", "VV.log(1);")


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
def test_dry_runs_side_by_side_each_get_their_own_report(
    ground_station, heli_one, user_a, user_b
) -> None:
    """Requests in threads of one web process, as a server runs them: each dry run is a
    process of its own, so neither sees the other's VV, fleet or V8."""
    programs = {
        user_a: "VV.task.execute({position: new VV.types.LatLngAlt(48.111, 12.861, 30),"
        " sensors: [VV.sensor.get('GPS')]}); VV.log('a');",
        user_b: "VV.log('b'); VV.log('b again');",
    }
    reports: dict[object, DryRunReport] = {}

    def run(user) -> None:
        try:
            report, problem = vv_dry_run_for_user(user=user, name="side", program=programs[user])
            assert problem is None and report is not None
            reports[user] = report
        finally:
            connection.close()  # this thread's own

    threads = [threading.Thread(target=run, args=(user,)) for user in programs]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=120)
    a, b = reports[user_a], reports[user_b]
    assert (a.status, len(a.tasks), a.log) == ("finished", 1, ("a",))
    assert (b.status, len(b.tasks), b.log) == ("finished", 0, ("b", "b again"))
