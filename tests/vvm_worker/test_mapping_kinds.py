"""The vehicle mapper and vehicle kinds (pure: no database): which kind may serve a task at
which altitude, which of them is cheapest, and what a customer is told when none can."""

from __future__ import annotations

import pytest
from shapely.geometry import Polygon

from fleet.geo import Position
from fleet.kinds import AERIAL, GROUND, SURFACE, UNDERWATER
from vvm_worker.mapping import VehicleCaps, map_task
from vvm_worker.runtime import TaskRequest

AREA = Polygon([(12.859, 48.109), (12.868, 48.109), (12.868, 48.114), (12.859, 48.114)])
NEAR = Position(48.1111, 12.8620, 0)  # a few metres from the task
FAR = Position(48.1135, 12.8670, 0)  # about 600 m from it
IDS: dict[str, int] = {}  # one id per vehicle name, the same on every run
# The altitude band each kind is configured with here (fleet.kinds allows it).
BAND = {AERIAL: (0.0, 120.0), GROUND: (0.0, 0.0), SURFACE: (0.0, 0.0), UNDERWATER: (-50.0, 0.0)}


def caps(name: str, kind: str, *, position: Position = NEAR, **kw: object) -> VehicleCaps:
    low, high = BAND[kind]
    base: dict[str, object] = {
        "id": IDS.setdefault(name, len(IDS) + 1),
        "name": name,
        "area": AREA,
        "min_altitude_m": low,
        "max_altitude_m": high,
        "sensors": frozenset({"GPS", "Thermometer"}),
        "active": True,
        "position": position,
        "max_speed_mps": 5.0,
        "kind": kind,
    }
    base.update(kw)
    return VehicleCaps(**base)  # type: ignore[arg-type]


def task(alt: float) -> TaskRequest:
    return TaskRequest(48.1111, 12.8619, alt, 2.0, ("Thermometer",))


def chosen(alt: float, fleet: list[VehicleCaps]) -> list[str]:
    return [v.name for v in map_task(task(alt), fleet).candidates]


def reason(alt: float, fleet: list[VehicleCaps]) -> str:
    decision = map_task(task(alt), fleet)
    assert decision.candidates == () and not decision.parked
    assert decision.reason is not None
    return decision.reason


@pytest.mark.parametrize("kind", [GROUND, SURFACE])
def test_a_task_at_0_m_goes_to_the_cheapest_of_an_aerial_and_a_planar_vehicle(kind: str) -> None:
    near_rover = [caps("Copter", AERIAL, position=FAR), caps("Rover", kind)]
    assert chosen(0, near_rover) == ["Rover", "Copter"]
    near_copter = [caps("Copter", AERIAL), caps("Rover", kind, position=FAR)]
    assert chosen(0, near_copter) == ["Copter", "Rover"]


def test_a_task_below_the_surface_goes_only_to_an_underwater_vehicle() -> None:
    fleet = [caps("Copter", AERIAL), caps("Rover", GROUND), caps("Boat", SURFACE)]
    assert chosen(-5, [*fleet, caps("Sub", UNDERWATER, position=FAR)]) == ["Sub"]


def test_an_underwater_vehicle_serves_the_surface_but_not_the_air() -> None:
    sub = caps("Sub", UNDERWATER)
    assert chosen(0, [sub]) == ["Sub"]
    assert chosen(10, [sub, caps("Copter", AERIAL, position=FAR)]) == ["Copter"]


def test_a_ground_vehicle_never_serves_a_task_above_the_ground() -> None:
    rover = caps("Rover", GROUND)
    assert chosen(10, [rover, caps("Copter", AERIAL, position=FAR)]) == ["Copter"]
    assert reason(10, [rover, caps("Boat", SURFACE)]) == (
        "no vehicle can serve the task at (48.111100, 12.861900) at 10 m: the task is 10 m "
        "above the ground: no aerial vehicle covers it"
    )


def test_a_task_below_the_surface_without_an_underwater_vehicle_says_so() -> None:
    fleet = [caps("Copter", AERIAL), caps("Rover", GROUND), caps("Boat", SURFACE)]
    text = reason(-5, fleet)
    assert text.endswith(": the task is 5 m below the surface: no underwater vehicle covers it")
    assert not any(v.name in text for v in fleet)  # customers are not told about vehicles


def test_a_task_deeper_than_the_underwater_vehicles_dive_says_how_deep_they_go() -> None:
    fleet = [caps("Sub", UNDERWATER), caps("Deep sub", UNDERWATER, min_altitude_m=-80.0)]
    assert chosen(-80, fleet) == ["Deep sub"]
    text = reason(-120, fleet)
    assert text.endswith(
        ": the task is 120 m below the surface: the underwater vehicles there dive to 80 m at most"
    )
    assert "Sub" not in text


def test_a_task_too_high_for_the_aerial_vehicles_keeps_the_altitude_message() -> None:
    text = reason(200, [caps("Copter", AERIAL), caps("Sub", UNDERWATER)])
    assert text.endswith("the altitude is outside what the vehicles there can fly (0 to 120 m)")


def test_the_faster_diver_is_the_cheaper_for_a_deep_task() -> None:
    slow = caps("A slow diver", UNDERWATER, climb_rate_mps=1.0, dive_rate_mps=0.5)
    fast = caps("B fast diver", UNDERWATER, climb_rate_mps=1.0, dive_rate_mps=4.0)
    assert fast.cost_s(task(-40)) < slow.cost_s(task(-40))
    assert chosen(-40, [slow, fast]) == ["B fast diver", "A slow diver"]
    # Without a dive rate it goes down at its climb rate.
    assert caps("Sub", UNDERWATER, climb_rate_mps=1.0).cost_s(task(-40)) == pytest.approx(
        slow.cost_s(task(-40)) / 2, rel=0.05
    )
