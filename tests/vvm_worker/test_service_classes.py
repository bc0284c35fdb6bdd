"""Service classes: a scenario's customers in them, and admission that holds back the queued
VVs of a class with slack while another class misses its target (never the one that misses,
never longer than the held class's own target allows), saying so in the customer's words.
Always with a second customer, who sees none of it."""

from __future__ import annotations

import copy
import itertools
from pathlib import Path
from typing import Any

import pytest
from django.core.exceptions import ValidationError

from accounts.models import Customer, ServiceClass
from missions.models import Migration, Task, TaskStatus, VirtualVehicle, VVStatus, WaitReason
from missions.waiting import vv_waiting
from tests.api_fixtures import token_client
from tests.factories import CustomerFactory, VehicleFactory
from vvm_worker.level_figures import ServiceClassSpec
from vvm_worker.scenario import Scenario, ScenarioError, parse_scenario
from vvm_worker.services import vv_admit_queued, vv_advance, vv_cancel, vv_submit
from vvm_worker.services.customers import customer_class_set, service_class_save
from vvm_worker.services.scenarios import scenario_apply
from vvm_worker.services.service_levels import (
    LEVEL_MIN_SAMPLES,
    LEVEL_WINDOW_S,
    class_held_nudge,
    classes_giving_way,
    service_level_holds,
    service_levels_by_class,
)

NOW = 10_000.0
PROGRAM = "VV.log('hello');\n"
# A standard class (120 s) with nothing read lately may wait its whole target.
HELD = (
    "held to keep other service levels; your class's target is met (it starts within 2 min at most)"
)

# --- scenarios ---------------------------------------------------------------------------------

SCENARIO: dict[str, Any] = {
    "ground_stations": [{"name": "GS Base", "position": [48.0, 12.0, 0]}],
    "vehicles": [],
    "customers": [
        {"name": "Gold A", "max_parallel_vvs": 2, "service_class": {"name": "gold", "p95_s": 30}},
        {
            "name": "Gold B",
            "max_parallel_vvs": 2,
            "service_class": {"name": "gold", "p95_s": 30, "weight": 1},
        },
        {
            "name": "Plain",
            "max_parallel_vvs": 1,
            "service_class": {"name": "standard", "p95_s": 120.5, "weight": 0.5},
        },
        {"name": "Nobody", "max_parallel_vvs": 1},
    ],
    "vvs": [],
}


def parsed(doc: dict[str, Any]) -> Scenario:
    return parse_scenario(doc, base_dir=Path("/nonexistent"))


def scenario_with(index: int, service_class: Any) -> dict[str, Any]:
    doc = copy.deepcopy(SCENARIO)
    doc["customers"][index]["service_class"] = service_class
    return doc


def test_a_scenario_customer_names_its_service_class() -> None:
    customers = {c.name: c for c in parsed(SCENARIO).customers}
    assert customers["Gold A"].service_class == ServiceClassSpec("gold", 30.0, 1.0)
    assert customers["Gold B"].service_class == customers["Gold A"].service_class
    assert customers["Plain"].service_class == ServiceClassSpec("standard", 120.5, 0.5)
    assert customers["Nobody"].service_class is None


@pytest.mark.parametrize(
    ("service_class", "where", "words"),
    [
        ({"name": "x", "p95_s": 0}, "customers[2].service_class.p95_s", "greater than 0"),
        ({"name": "x", "p95_s": "30"}, "customers[2].service_class.p95_s", "must be a number"),
        (
            {"name": "x", "p95_s": 30, "weight": -1},
            "customers[2].service_class.weight",
            "greater than 0",
        ),
        ({"name": "x"}, "customers[2].service_class", "missing required key 'p95_s'"),
        ({"name": "", "p95_s": 3}, "customers[2].service_class.name", "must not be empty"),
        ({"name": "x" * 61, "p95_s": 3}, "customers[2].service_class.name", "at most 60"),
        ({"name": "x", "p95_s": 3, "tier": 1}, "customers[2].service_class", "unknown key"),
        ("gold", "customers[2].service_class", "must be an object"),
    ],
)
def test_a_bad_service_class_is_refused_saying_where(service_class, where, words) -> None:
    with pytest.raises(ScenarioError) as refused:
        parsed(scenario_with(2, service_class))
    assert refused.value.path == where
    assert words in refused.value.message


def test_one_class_given_two_ways_is_refused_naming_both_customers() -> None:
    with pytest.raises(ScenarioError) as refused:
        parsed(scenario_with(1, {"name": "gold", "p95_s": 45}))
    assert refused.value.path == "customers[1].service_class"
    message = refused.value.message
    assert "'Gold B'" in message and "'Gold A'" in message and "customers[0]" in message
    assert "45" in message and "30" in message


def test_a_scenario_puts_its_classes_and_customers_in_the_database(db) -> None:
    scenario = parsed(SCENARIO)
    loaded = scenario_apply(scenario=scenario, logins=False)
    classes = {c.name: (c.p95_s, c.weight) for c in ServiceClass.objects.all()}
    assert classes == {"gold": (30.0, 1.0), "standard": (120.5, 0.5)}
    by_name = {name: c.service_class for name, c in loaded.customers.items()}
    assert by_name["Gold A"] == by_name["Gold B"] == ServiceClass.objects.get(name="gold")
    assert by_name["Plain"].name == "standard" and by_name["Nobody"] is None
    scenario_apply(scenario=scenario, logins=False)  # twice: nothing changes
    assert ServiceClass.objects.count() == 2
    assert Customer.objects.get(name="Gold A").service_class.name == "gold"


# --- admission ---------------------------------------------------------------------------------

_rows = itertools.count()


def load_of(
    customer: Customer,
    *,
    latencies: list[float] | tuple[()] = (),
    open_ages: list[float] | tuple[()] = (),
    now: float = NOW,
) -> VirtualVehicle:
    """A running VV of the customer with tasks read ``latencies`` seconds after their request
    (each read a second before ``now``) and open tasks requested ``open_ages`` seconds before
    ``now``: what the fleet did for the customer lately."""
    vv = VirtualVehicle.objects.create(
        customer=customer,
        name=f"load {next(_rows)}",
        program=PROGRAM,
        seed=1,
        start_ms=0,
        submitted_s=0.0,
        status=VVStatus.RUNNING,
    )
    done = [(TaskStatus.DONE, now - 1 - s, now - 1) for s in latencies]
    open_ = [(TaskStatus.OPEN, now - s, None) for s in open_ages]
    Task.objects.bulk_create(
        Task(
            vv=vv,
            q=q,
            lat=48.0,
            lng=12.0,
            alt=50.0,
            tolerance_m=2.0,
            sensors=["CO2"],
            status=status,
            requested_s=requested_s,
            done_s=done_s,
        )
        for q, (status, requested_s, done_s) in enumerate([*done, *open_], start=1)
    )
    return vv


@pytest.fixture
def vvm(vvm_factory, ground_station):
    made = vvm_factory()
    made.clock.t = NOW
    return made


@pytest.fixture
def premium(db) -> ServiceClass:
    return service_class_save(name="premium", p95_s=30.0)


@pytest.fixture
def slow_premium(premium, vvm) -> Customer:
    """Another customer of the class, whose tasks the fleet reads late: 41 s (p95)."""
    other = CustomerFactory(name="Customer C", max_parallel_vvs=50)
    customer_class_set(customer=other, service_class=premium, vvm=vvm)
    load_of(other, latencies=[10.0] * LEVEL_MIN_SAMPLES + [41.0] * 3, open_ages=[2.0])
    return other


def waiting_of(vv: VirtualVehicle):
    vv.refresh_from_db()
    return vv_waiting(vv, tasks_open=0)


@pytest.fixture
def standard(db) -> ServiceClass:
    return service_class_save(name="standard", p95_s=120.0, weight=1.0)


def test_a_class_with_slack_is_held_back_while_another_misses_its_target_and_says_why(
    customer_a, customer_b, user_a, user_b, standard, slow_premium, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    held = vv_submit(customer=customer_a, name="held", program=PROGRAM, vvm=vvm)
    assert held.status == VVStatus.QUEUED
    waiting = waiting_of(held)
    assert (waiting.reason, waiting.message, waiting.since_s) == (
        WaitReason.SERVICE_LEVEL,
        HELD,
        NOW,
    )
    for secret in ("Customer C", "premium", "Heli"):
        assert secret not in waiting.message
    shown = token_client(user_a).get(f"/api/v1/vvs/{held.pk}/").json()["waiting"]
    assert (shown["reason"], shown["message"]) == ("service_level", HELD)
    assert token_client(user_b).get(f"/api/v1/vvs/{held.pk}/").status_code == 404
    # A customer without a class is never held back: it was promised nothing to wait for.
    free = vv_submit(customer=customer_b, name="free", program=PROGRAM, vvm=vvm)
    assert free.status == VVStatus.RUNNING and waiting_of(free) is None


def test_the_class_that_misses_its_target_is_never_held(customer_a, premium, slow_premium, vvm):
    customer_class_set(customer=customer_a, service_class=premium, vvm=vvm)
    vv = vv_submit(customer=customer_a, name="p", program=PROGRAM, vvm=vvm)
    assert vv.status == VVStatus.RUNNING and waiting_of(vv) is None


def test_a_class_without_slack_is_not_held_back(customer_a, standard, slow_premium, vvm) -> None:
    # Standard keeps its target, but at 70 s of its 120 s: more than half. Holding its VVs
    # back would risk its own promise.
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    load_of(customer_a, latencies=[70.0] * LEVEL_MIN_SAMPLES, open_ages=[5.0])
    vv = vv_submit(customer=customer_a, name="s", program=PROGRAM, vvm=vvm)
    assert vv.status == VVStatus.RUNNING


def test_held_back_vvs_start_once_the_other_class_is_back_within_target(
    customer_a, standard, slow_premium, premium, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    held = vv_submit(customer=customer_a, name="held", program=PROGRAM, vvm=vvm)
    vv_submit(customer=customer_a, name="held too", program=PROGRAM, vvm=vvm)
    vvm.clock.t += 60  # premium still late: only the time passes
    assert vv_admit_queued(customer_id=customer_a.pk, vvm=vvm) == []
    assert waiting_of(held).since_s == NOW, "held since it was first held"
    # One hold, recorded once however often admission looks again, for the report.
    (hold,) = service_level_holds(since_s=0.0, until_s=NOW + 1_000, now_s=vvm.clock.t)
    assert (hold.customer, hold.service_class, hold.for_classes) == (
        "Customer A",
        "standard",
        ("premium",),
    )
    assert (hold.started_s, hold.ended_s, hold.held_s, hold.vvs_held) == (NOW, None, 60.0, 2)
    # The fleet catches up with premium: many of its tasks read fast.
    load_of(slow_premium, latencies=[5.0] * 60)
    vvm.dispatcher.slots.clear()
    class_held_nudge(service_class_id=premium.pk, vvm=vvm)
    assert vvm.dispatcher.slots == [customer_a.pk], "only the customer whose VVs are held"
    vvm.clock.t += 5
    started = vv_admit_queued(customer_id=customer_a.pk, vvm=vvm)
    assert {vv.name for vv in started} == {"held", "held too"}
    held.refresh_from_db()
    assert held.status == VVStatus.RUNNING and waiting_of(held) is None
    (hold,) = service_level_holds(since_s=NOW + 30, until_s=NOW + 1_000, now_s=NOW + 1_000)
    assert (hold.ended_s, hold.held_s) == (NOW + 65, 35.0), "the hold ended; the period's part"
    classes = {c.got.service_class: c for c in service_levels_by_class(holds=[hold])}
    assert (classes["premium"].holds_for_it, classes["premium"].holds) == (1, 0)


def test_a_held_back_vv_waits_no_longer_than_its_class_has_slack(
    customer_a, standard, slow_premium, vvm
) -> None:
    # Standard's p95 is 50 s of its 120 s: its requests could wait 70 s more and it would
    # still keep its target. Premium stays late all along.
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    load_of(customer_a, latencies=[50.0] * LEVEL_MIN_SAMPLES)
    held = vv_submit(customer=customer_a, name="held", program=PROGRAM, vvm=vvm)
    assert "(it starts within 70 s at most)" in waiting_of(held).message
    vvm.clock.t = NOW + 69.0
    assert vv_admit_queued(customer_id=customer_a.pk, vvm=vvm) == []
    vvm.clock.t = NOW + 70.0
    (started,) = vv_admit_queued(customer_id=customer_a.pk, vvm=vvm)
    assert started.pk == held.pk


def test_the_end_of_a_vv_of_a_class_looks_again_at_the_held_ones(
    customer_a, customer_b, standard, slow_premium, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    vv_submit(customer=customer_a, name="held", program=PROGRAM, vvm=vvm)
    running_b = vv_submit(customer=customer_b, name="b", program=PROGRAM, vvm=vvm)
    (load,) = VirtualVehicle.objects.filter(customer=slow_premium)
    vvm.dispatcher.slots.clear()
    vv_cancel(vv_id=running_b.pk, vvm=vvm)  # customer B has no class: nobody else is asked
    assert vvm.dispatcher.slots == [customer_b.pk]
    vv_cancel(vv_id=load.pk, vvm=vvm)  # premium's open task ends with it
    assert vvm.dispatcher.slots == [customer_b.pk, slow_premium.pk, customer_a.pk]
    # Its task cancelled, premium has no open task left: the fleet has caught up with it.
    (started,) = vv_admit_queued(customer_id=customer_a.pk, vvm=vvm)
    assert started.status == VVStatus.RUNNING


def test_a_flood_of_a_class_with_slack_is_held_back_not_the_premium_that_misses(
    customer_a, customer_b, premium, standard, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=premium, vvm=vvm)
    customer_class_set(customer=customer_b, service_class=standard, vvm=vvm)
    load_of(customer_a, latencies=[45.0] * LEVEL_MIN_SAMPLES, open_ages=[3.0])
    load_of(customer_b, latencies=[20.0] * LEVEL_MIN_SAMPLES, open_ages=[4.0])
    flood = vv_submit(customer=customer_b, name="flood", program=PROGRAM, vvm=vvm)
    assert flood.status == VVStatus.QUEUED
    assert waiting_of(flood).reason == WaitReason.SERVICE_LEVEL
    assert vv_submit(customer=customer_a, name="p", program=PROGRAM, vvm=vvm).status == (
        VVStatus.RUNNING
    )


@pytest.mark.parametrize(
    ("latencies", "open_ages"),
    [
        ([41.0] * (LEVEL_MIN_SAMPLES - 2), [41.0]),  # too few to say anything yet
        ([41.0] * LEVEL_MIN_SAMPLES, []),  # nothing of premium is open: caught up
        ([20.0] * LEVEL_MIN_SAMPLES, [29.0]),  # premium within its target
    ],
)
def test_admission_does_not_hold_back_without_a_reason(
    customer_a, customer_b, premium, standard, vvm, latencies, open_ages
) -> None:
    customer_class_set(customer=customer_b, service_class=premium, vvm=vvm)
    load_of(customer_b, latencies=latencies, open_ages=open_ages)
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    vv = vv_submit(customer=customer_a, name="vv", program=PROGRAM, vvm=vvm)
    assert vv.status == VVStatus.RUNNING


def test_tasks_read_before_the_window_do_not_count(
    customer_a, customer_b, premium, standard, vvm
) -> None:
    customer_class_set(customer=customer_b, service_class=premium, vvm=vvm)
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    load_of(customer_b, open_ages=[1.0] * LEVEL_MIN_SAMPLES)
    later = vvm.clock.t = NOW + LEVEL_WINDOW_S + 1
    vv = vv_submit(customer=customer_a, name="vv", program=PROGRAM, vvm=vvm)
    assert vv.status == VVStatus.QUEUED, "premium's open tasks waited longer than the window"
    # All of them read late, but before the window; one new task is open.
    Task.objects.filter(status=TaskStatus.OPEN).update(status=TaskStatus.DONE, done_s=NOW)
    load_of(customer_b, open_ages=[1.0], now=later)
    (started,) = vv_admit_queued(customer_id=customer_a.pk, vvm=vvm)
    assert started.pk == vv.pk


def test_a_class_is_saved_and_set_through_the_services(customer_a, customer_b, vvm) -> None:
    gold = service_class_save(name="gold", p95_s=30.0, weight=2.0)
    assert service_class_save(name="gold", p95_s=25.0).pk == gold.pk  # by name: changed
    gold.refresh_from_db()
    assert (gold.p95_s, gold.weight) == (25.0, 1.0)
    for bad, field in [
        ({"name": "x", "p95_s": 0.0}, "p95_s"),
        ({"name": "x", "p95_s": float("nan")}, "p95_s"),
        ({"name": "x", "p95_s": 5.0, "weight": 0.0}, "weight"),
        ({"name": "", "p95_s": 5.0}, "name"),
    ]:
        with pytest.raises(ValidationError) as refused:
            service_class_save(**bad)
        assert field in refused.value.message_dict
    vvm.dispatcher.slots.clear()
    customer_class_set(customer=customer_a, service_class=gold, vvm=vvm)
    assert vvm.dispatcher.slots == [customer_a.pk], "its queued VVs are looked at again"
    with pytest.raises(ValidationError, match="service_class"):
        customer_class_set(customer=customer_a, service_class=ServiceClass(name="new"), vvm=vvm)
    customer_a.refresh_from_db()
    customer_b.refresh_from_db()
    assert customer_a.service_class == gold and customer_b.service_class is None
    customer_class_set(customer=customer_a, service_class=None, vvm=vvm)
    customer_a.refresh_from_db()
    assert customer_a.service_class is None


def test_held_back_vvs_start_in_the_simulation_when_the_other_class_catches_up(
    platform, ground_station, customer_a, customer_b, premium, standard
) -> None:
    """No sweep runs in ``simulate``: the end of the late class's tasks must start the VVs
    held back for it."""
    platform.add_vehicle_loop(VehicleFactory(name="Heli One"))
    platform.clock.t = NOW
    customer_class_set(customer=customer_b, service_class=premium, vvm=platform.vvm)
    customer_class_set(customer=customer_a, service_class=standard, vvm=platform.vvm)
    late = load_of(customer_b, latencies=[41.0] * LEVEL_MIN_SAMPLES)
    late.status, late.finished_s = VVStatus.FINISHED, NOW - 1
    late.save()
    one_task = (
        "var co2 = VV.sensor.get('CO2');\n"
        "VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(48.1111, 12.8619, 50),"
        " tolerance: 2, sensors: [co2]});\n"
    )
    first = vv_submit(customer=customer_b, name="first", program=one_task, vvm=platform.vvm)
    platform.drain(until=lambda: Task.objects.filter(vv=first).exists())
    held = vv_submit(customer=customer_a, name="held", program=one_task, vvm=platform.vvm)
    assert held.status == VVStatus.QUEUED
    assert waiting_of(held).reason == WaitReason.SERVICE_LEVEL
    platform.drain()
    held.refresh_from_db()
    first.refresh_from_db()
    assert first.status == held.status == VVStatus.FINISHED
    assert held.started_s >= Task.objects.get(vv=first).done_s


def test_an_rv_weighs_a_task_routed_to_it_by_its_class_without_reading_it_again(
    customer_a, customer_b, vvm, django_assert_num_queries
) -> None:
    # A VV's next task put on an RV's list in a unit of work that holds the VV (read with its
    # customer and class) reaches the RV's plan with the class's weight, read with the VV.
    from vvm_worker.executor import DatabaseStore
    from vvm_worker.services.store import locked_vv

    gold = service_class_save(name="gold", p95_s=30.0, weight=2.5)
    customer_class_set(customer=customer_a, service_class=gold, vvm=vvm)
    vehicle = VehicleFactory(name="Heli One")
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, ticks=True)
    assert store.open_tasks() == []
    added = []
    for customer in (customer_a, customer_b):
        vv = locked_vv(vv_submit(customer=customer, name="vv", program=PROGRAM, vvm=vvm).pk)
        task = Task.objects.create(
            vv=vv,
            q=9,
            lat=1.0,
            lng=2.0,
            alt=20.0,
            tolerance_m=5.0,
            sensors=["temperature"],
            requested_s=NOW,
            vehicle=vehicle,
        )
        added.append(task)
    store.add(added)
    with django_assert_num_queries(0):
        weights = [t.weight for t in store.open_tasks()]
    assert weights == [2.5, 1.0]


# --- the mapper's reserve ----------------------------------------------------------------------

ONE_TASK = """var co2 = VV.sensor.get('CO2');
VV.task.execute({position: new VV.types.LatLngAlt(48.1111, 12.8619, 50), sensors: [co2]});
"""


def test_classes_with_slack_give_way_while_a_class_without_it_is_served(
    customer_a, standard, slow_premium, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    load_of(customer_a, latencies=[10.0] * LEVEL_MIN_SAMPLES, open_ages=[5.0])
    # Premium reads at 41 s for its 30 s: standard (10 s of 120) and customers without a class
    # give way to it.
    assert classes_giving_way(now_s=NOW, vvm=vvm) == {standard.pk, None}
    # Premium catches up (its late tasks leave the window); routing looks again 10 s later.
    Task.objects.filter(vv__customer=slow_premium).delete()
    load_of(slow_premium, latencies=[5.0] * LEVEL_MIN_SAMPLES, now=NOW + 5)
    assert classes_giving_way(now_s=NOW + 5, vvm=vvm) == {standard.pk, None}
    assert classes_giving_way(now_s=NOW + 10, vvm=vvm) == frozenset()


def test_nobody_gives_way_without_a_class_served_or_when_every_class_has_slack(
    customer_a, standard, vvm
) -> None:
    customer_class_set(customer=customer_a, service_class=standard, vvm=vvm)
    assert classes_giving_way(now_s=NOW, vvm=vvm) == frozenset()  # nothing served lately
    load_of(customer_a, latencies=[10.0] * LEVEL_MIN_SAMPLES)  # 10 s of 120: slack
    vvm.giving_way_seen = None
    assert classes_giving_way(now_s=NOW, vvm=vvm) == frozenset()  # nobody to give way to
    load_of(customer_a, latencies=[70.0] * LEVEL_MIN_SAMPLES)  # now 70 s: no slack
    vvm.giving_way_seen = None
    # Only the customers without a class give way: standard has nothing to give.
    assert classes_giving_way(now_s=NOW, vvm=vvm) == {None}


def test_a_vv_giving_way_leaves_the_reserve_rv_to_the_class_without_slack(
    customer_a, customer_b, standard, premium, slow_premium, vvm
) -> None:
    # Two RVs over one area at one depot. Heli Two carries a task of a standard customer
    # already; Heli One is idle, cheaper for any new task. Standard has slack while premium
    # misses: a new VV of a customer without a class goes to Heli Two, leaving Heli One to
    # premium's, which takes it.
    two = VehicleFactory(name="Heli Two")
    VehicleFactory(name="Heli One")
    steady = CustomerFactory(name="Customer D", max_parallel_vvs=50)
    customer_class_set(customer=steady, service_class=standard, vvm=vvm)
    customer_class_set(customer=customer_b, service_class=premium, vvm=vvm)
    load_of(steady, latencies=[10.0] * LEVEL_MIN_SAMPLES)
    Task.objects.filter(vv=load_of(steady, open_ages=[5.0])).update(vehicle=two)
    plain = vv_submit(customer=customer_a, name="plain", program=ONE_TASK, vvm=vvm)
    premium_vv = vv_submit(customer=customer_b, name="premium", program=ONE_TASK, vvm=vvm)
    for vv in (plain, premium_vv):
        vv_advance(vv_id=vv.pk, vvm=vvm)
    assert (moved_to(plain), moved_to(premium_vv)) == ("Heli Two", "Heli One")
    # With no class under pressure, the same kind of VV takes the cheapest RV.
    vvm.giving_way_seen = (NOW, frozenset())
    again = vv_submit(customer=customer_a, name="plain 2", program=ONE_TASK, vvm=vvm)
    vv_advance(vv_id=again.pk, vvm=vvm)
    assert moved_to(again) == "Heli One"


def moved_to(vv: VirtualVehicle) -> str:
    """The RV the VV last migrated to."""
    return Migration.objects.filter(vv=vv).latest("at_s", "id").to_name
