"""The task executor on the platform: an RV's control loop (``vvm_worker.control``) with its
work in the database, its sensors read for the VVs, and the one builder of an RV's loop that
``simulate`` and the RV workers share.

The database store keeps what the loop asks again and again (the RV's open tasks and its
status) until it is told that they changed (``VehicleRig.changed``: the dispatcher's
``vehicle_changed``, a sweep) or finds out (a task completed by someone else): a plan reads
nothing that has not changed.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

from django.conf import settings

from fleet.driving import Driver
from fleet.geo import Position
from fleet.models import SensorType, Vehicle, VehicleStatus
from fleet.simulation import SimVehicle
from fleet.simulation import VehicleSpec as KinematicSpec
from missions.models import ACTIVE_STATUSES, Task, TaskStatus, VirtualVehicle
from vvm_worker.control import (
    Area,
    ControlLoop,
    LoopConfig,
    LoopTask,
    Scheduler,
    VehicleState,
)
from vvm_worker.planning import TravelTime, make_planner
from vvm_worker.sensing import read_sensors
from vvm_worker.services import VVM, task_complete, vehicle_record_state, vehicle_set_status

_SDC_TTL_S = 10.0


class DatabaseStore:
    """An RV's work as the platform keeps it (``vvm_worker.control.Store``)."""

    def __init__(self, *, vehicle_id: int, vvm: VVM, live: bool = False) -> None:
        self.vehicle_id = vehicle_id
        self.vvm = vvm
        self.live = live
        self._tasks: list[LoopTask] | None = None
        self._status: str | None = None
        self._aboard: list[dict[str, Any]] = []

    def changed(self) -> None:
        """The RV's tasks or status may have changed: read them again when next asked."""
        self._tasks = None
        self._status = None

    def open_tasks(self) -> Sequence[LoopTask]:
        if self._tasks is None:
            rows = (
                Task.objects.filter(vehicle_id=self.vehicle_id, status=TaskStatus.OPEN)
                .order_by("requested_s", "id")
                .values_list(
                    "pk", "lat", "lng", "alt", "tolerance_m", "requested_s", "sensors", "vv_id", "q"
                )
            )
            self._tasks = [
                LoopTask(
                    id=pk,
                    position=Position(lat, lng, alt),
                    tolerance_m=tolerance_m,
                    requested_s=requested_s,
                    sensors=tuple(sensors),
                    vv=vv_id,
                    # The tasks of one request (an executeAll batch) share a group.
                    group=f"{vv_id}:{q}",
                )
                for pk, lat, lng, alt, tolerance_m, requested_s, sensors, vv_id, q in rows
            ]
        return self._tasks

    def status(self) -> str:
        if self._status is None:
            self._status = str(
                Vehicle.objects.values_list("status", flat=True).get(pk=self.vehicle_id)
            )
        return self._status

    def set_status(self, status: str, *, expected: str | None = None) -> None:
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        if expected is None or vehicle.status == expected:
            vehicle_set_status(vehicle=vehicle, status=VehicleStatus(status), vvm=self.vvm)
        self._status = None

    def complete(self, task: LoopTask, readings: list[dict[str, Any]], now_s: float) -> None:
        done = task_complete(
            task_id=task.id,
            readings=readings,
            vvm=self.vvm,
            vehicle_id=self.vehicle_id,
            vv_id=task.vv,
        )
        if not done:  # no longer this RV's (cancelled, moved on): read the tasks again
            self._tasks = None
        elif self._tasks is not None:
            self._tasks = [t for t in self._tasks if t.id != task.id]

    def record_state(self, state: VehicleState, *, moved: bool) -> None:
        if moved or self.live:  # the track and the map need the VVs aboard
            self._aboard = self._read_aboard()
        vehicle_record_state(
            vehicle_id=self.vehicle_id,
            t_s=state.t_s,
            carrying=[vv["id"] for vv in self._aboard] if moved else [],
            position=state.position,
            phase=state.phase,
            distance_m=state.distance_m,
            flight_s=state.flight_s,
            planner_state=state.planner_state,
        )

    def area(self) -> Area:
        vehicle = Vehicle.objects.get(pk=self.vehicle_id)
        return Area(vehicle.area_polygon, vehicle.min_altitude_m, vehicle.max_altitude_m)

    def aboard(self) -> list[dict[str, Any]]:
        return self._aboard

    def _read_aboard(self) -> list[dict[str, Any]]:
        return [
            {"id": str(pk), "name": name, "customer": customer_id}
            for pk, name, customer_id in VirtualVehicle.objects.filter(
                host_rv_id=self.vehicle_id, status__in=ACTIVE_STATUSES
            )
            .order_by("submitted_s", "id")
            .values_list("pk", "name", "customer_id")
        ]


class PlatformSensing:
    """The readings of a task's sensors from the VVM's sensor world (``vvm_worker.control.
    Sensing``), by the SDC entries the sensors name."""

    def __init__(self, vvm: VVM) -> None:
        self.vvm = vvm
        self._sdc: tuple[float, dict[str, dict[str, Any]]] | None = None

    def __call__(
        self, task: LoopTask, position: Position, now_s: float, battery: float | None
    ) -> list[dict[str, Any]]:
        catalog = self._catalog()
        return read_sensors(
            field=self.vvm.field,
            sensors=[catalog[name] for name in task.sensors],
            position=position,
            time_s=now_s,
            epoch_ms=self.vvm.clock.epoch_ms(now_s),
            battery_fraction=battery,
            seed=self.vvm.world_seed,
        )

    def _catalog(self) -> dict[str, dict[str, Any]]:
        # The SDC changes rarely; read it again now and then, not at every stop.
        now = time.monotonic()
        if self._sdc is None or now - self._sdc[0] > _SDC_TTL_S:
            self._sdc = (now, {s.name: s.as_catalog_entry() for s in SensorType.objects.all()})
        return self._sdc[1]


@dataclass
class VehicleRig:
    """One RV as a host runs it: its driver, its store and its control loop."""

    vehicle_id: int
    name: str
    driver: Driver
    store: DatabaseStore
    loop: ControlLoop

    def changed(self) -> Callable[[], None]:
        """The RV's tasks or status were just changed: forget what the store read, and the
        loop's wake-up to run (see ``ControlLoop.changed``)."""
        self.store.changed()
        return self.loop.changed()


def kinematics(vehicle: Vehicle, *, scale: float = 1.0) -> KinematicSpec:
    """The vehicle's kinematics, ``scale`` times faster (time acceleration of a simulated
    vehicle: distances stay right, flights and the battery's endurance shorten)."""
    return KinematicSpec(
        max_speed_mps=vehicle.max_speed_mps * scale,
        climb_rate_mps=vehicle.climb_rate_mps * scale,
        battery_s=None if vehicle.battery_s is None else vehicle.battery_s / scale,
    )


def build_rig(
    vehicle: Vehicle,
    *,
    vvm: VVM,
    scheduler: Scheduler,
    planner: str,
    scale: float = 1.0,
    driver: Driver | None = None,
    plan_time_limit_s: float | None = None,
    live: bool = False,
) -> VehicleRig:
    """An RV's control loop over the database: for ``simulate`` (one per RV, one queue) and
    for the RV workers (real time). ``driver``: the vehicle's (a MAVLink autopilot), else a
    simulated vehicle at its depot with ``kinematics(vehicle, scale=scale)``."""
    spec = kinematics(vehicle, scale=scale)
    if driver is None:
        driver = SimVehicle(spec, vehicle.depot, now_s=vvm.clock.now_s())
    store = DatabaseStore(vehicle_id=vehicle.pk, vvm=vvm, live=live)
    loop = ControlLoop(
        name=vehicle.name,
        driver=driver,
        planner=make_planner(
            planner,
            travel_time=TravelTime(spec.max_speed_mps, spec.climb_rate_mps),
            time_limit_s=plan_time_limit_s,
        ),
        store=store,
        scheduler=scheduler,
        clock=vvm.clock.now_s,
        sensing=PlatformSensing(vvm),
        config=LoopConfig(
            battery_s=spec.battery_s,
            reserve=settings.CPCC_BATTERY_RESERVE,
            recharge_s=settings.CPCC_RECHARGE_S / scale,
            standby_s=settings.CPCC_STANDBY_S / scale,
            live=live,
        ),
    )
    return VehicleRig(vehicle.pk, vehicle.name, driver, store, loop)
