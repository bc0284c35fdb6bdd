"""Fleet changes and RV workers' leases, and what they mean for the VVs aboard."""

from __future__ import annotations

from django.db import transaction

from fleet.models import Vehicle, VehicleStatus
from missions.models import (
    ACTIVE_STATUSES,
    ENDED_STATUSES,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from vvm_worker.services.base import VVM, as_datetime, logger
from vvm_worker.services.routing import (
    fleet_caps,
    migrate_to_ground_station,
    online_vehicles,
    record_migration,
    release_tasks,
    request_of,
    vehicle_caps,
)


def vehicle_set_status(*, vehicle: Vehicle, status: VehicleStatus, vvm: VVM) -> None:
    """Put an RV into service, into maintenance, or remove it, without disturbing customers.

    The VVs aboard an RV that leaves service move to RVs that can serve their tasks, or wait
    on a ground station until one can; VVs waiting on a ground station are looked at again
    whenever an RV comes into service.
    """
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == status:
            return
        vehicle.status = status
        vehicle.save(update_fields=["status", "updated"])
        if status != VehicleStatus.ACTIVE:
            aboard = list(
                vehicle.vvs.exclude(status__in=ENDED_STATUSES).values_list("pk", flat=True)
            )
            Task.objects.filter(vehicle=vehicle, status=TaskStatus.OPEN).update(vehicle=None)
            for vv_id in aboard:
                vvm.dispatcher.vv_arrived(vv_id)
        logger.info("vehicle status", extra={"vehicle": vehicle.name, "status": status})
        vvm.dispatcher.vehicle_changed(vehicle.pk)
    if status == VehicleStatus.ACTIVE:
        vehicle_register(vehicle=vehicle, vvm=vvm)


def vvs_reroute_waiting(*, vvm: VVM) -> None:
    """Look again at every VV waiting on a ground station for an RV (after a fleet change)."""
    waiting = VirtualVehicle.objects.filter(
        status=VVStatus.RUNNING, host_gs__isnull=False, pending__isnull=False
    ).order_by("submitted_s", "id")
    for vv_id in waiting.values_list("pk", flat=True):
        vvm.dispatcher.vv_arrived(vv_id)


def vehicle_register(*, vehicle: Vehicle, vvm: VVM) -> None:
    """An RV came into service (new, or back from maintenance): it takes work at once.

    VVs waiting on a ground station for an RV are routed again, and a VV whose open tasks all
    lie in this RV's reach moves to it when it would get there sooner than the RV it is on
    (the mapper's estimate: flight time plus the queue of tasks). The caller has saved the
    vehicle and its sensors.
    """
    vvs_reroute_waiting(vvm=vvm)
    with transaction.atomic():
        vehicle = Vehicle.objects.prefetch_related("sensors").get(pk=vehicle.pk)
        if vehicle.status != VehicleStatus.ACTIVE:
            return
        newcomer = vehicle_caps(vehicle)
        fleet = {c.id: c for c in fleet_caps(vvm)}
        aboard_others = (
            VirtualVehicle.objects.select_for_update(of=("self",))
            .filter(status=VVStatus.RUNNING, host_rv__isnull=False, pending__isnull=False)
            .exclude(host_rv=vehicle)
            .select_related("customer", "host_rv")
            .order_by("submitted_s", "id")
        )
        for vv in aboard_others:
            tasks = list(vv.tasks.filter(status=TaskStatus.OPEN))
            host = fleet.get(vv.host_rv_id)  # type: ignore[arg-type]
            requests = [request_of(t) for t in tasks]
            if not requests or host is None or not all(newcomer.can_serve(r) for r in requests):
                continue
            if newcomer.cost_s(requests[0]) >= host.cost_s(requests[0]):
                continue
            release_tasks(vv, vvm)
            record_migration(vv, to=vehicle, reason="a closer vehicle came into service", vvm=vvm)
            vv.status = VVStatus.MIGRATING
            vv.save(update_fields=["host_rv", "host_gs", "status", "updated"])
            vvm.dispatcher.vv_arrived(vv.pk)
            newcomer = vehicle_caps(vehicle, newcomer.open_tasks + len(tasks))
    vvm.dispatcher.vehicle_changed(vehicle.pk)


def vehicle_heartbeat(*, vehicle_id: int, vvm: VVM) -> None:
    """The vehicle's worker is alive (it renews its lease)."""
    Vehicle.objects.filter(pk=vehicle_id).update(worker_seen=as_datetime(vvm, vvm.clock.now_s()))


def vehicles_check_leases(*, vvm: VVM) -> list[str]:
    """Move the VVs off every RV whose worker has stopped reporting; returns those RVs' names.

    The VVs wait on a ground station, which routes them to an RV that can serve them (this
    one again, if its worker comes back). Whatever that worker might still report for their
    tasks is refused (``task_complete`` checks the vehicle), so no reading is taken twice.
    """
    assert vvm.lease_s is not None
    gone = []
    online = online_vehicles(vvm).values("pk")
    stale = (
        Vehicle.objects.exclude(pk__in=online).filter(vvs__status__in=ACTIVE_STATUSES).distinct()
    )
    for vehicle in stale:
        with transaction.atomic():
            stranded = (
                VirtualVehicle.objects.select_for_update(of=("self",))
                .filter(host_rv=vehicle, status__in=ACTIVE_STATUSES)
                .select_related("customer", "host_gs", "host_rv")
            )
            for vv in stranded:
                migrate_to_ground_station(
                    vv, reason="its vehicle's worker stopped reporting", vvm=vvm
                )
                vv.save()
        gone.append(vehicle.name)
        logger.warning("vehicle worker lost", extra={"vehicle": vehicle.name})
    return gone


def vehicle_reconfigured(*, vehicle: Vehicle, vvm: VVM) -> None:
    """An RV's reach changed (area, altitude range, sensors): the tasks planned on it are taken
    off it and the VVs aboard route them again; they stay if it can still serve them and move
    to an RV that can otherwise. An RV in service with a larger reach takes work at once."""
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == VehicleStatus.REMOVED:
            return
        Task.objects.filter(vehicle=vehicle, status=TaskStatus.OPEN).update(vehicle=None)
        aboard = vehicle.vvs.exclude(status__in=ENDED_STATUSES).values_list("pk", flat=True)
        for vv_id in aboard:
            vvm.dispatcher.vv_arrived(vv_id)
        vvm.dispatcher.vehicle_changed(vehicle.pk)
    if vehicle.status == VehicleStatus.ACTIVE:
        vehicle_register(vehicle=vehicle, vvm=vvm)
