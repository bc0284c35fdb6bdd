"""The fleet: adding and configuring RVs and ground stations, RVs entering and leaving
service, their workers' leases and live state, and what each change means for the VVs aboard."""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Sequence
from typing import Any, TypedDict

from django.core.exceptions import ValidationError
from django.db import transaction
from django.db.models.functions import Now
from django.utils import timezone

from fleet.geo import Position
from fleet.models import (
    GroundStation,
    NoFlyZone,
    PilotDuty,
    RallyPoint,
    SensorType,
    Vehicle,
    VehicleCommand,
    VehicleStatus,
)
from fleet.selectors import sensors_not_carried
from missions.models import (
    ACTIVE_STATUSES,
    ENDED_STATUSES,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
)
from vvm_worker.control import VehicleState
from vvm_worker.services.base import VVM, logger, sensor_entries
from vvm_worker.services.batteries import battery_observe
from vvm_worker.services.routing import (
    fleet_caps,
    online_vehicles,
    request_of,
    vehicle_caps,
    vv_migrate_to_ground_station,
    vv_record_migration,
    vv_release_tasks,
)
from vvm_worker.services.store import (
    LandingRow,
    TakeOffRow,
    flights_write,
    track_points_aboard,
    vehicle_report,
)

# Changing any of these may leave tasks planned on the RV that it can no longer serve.
REACH_FIELDS = ("area", "min_altitude_m", "max_altitude_m")


class VehicleConfig(TypedDict, total=False):
    """What a provider configures on an RV (model field names)."""

    name: str
    driver: str
    driver_url: str
    depot_lat: float
    depot_lng: float
    depot_alt: float
    area: list[list[float]]
    min_altitude_m: float
    max_altitude_m: float
    max_speed_mps: float
    climb_rate_mps: float
    battery_s: float | None
    sensor_sources: dict[str, Any]
    kind: str
    dive_rate_mps: float | None
    turn_rate_dps: float | None


class GroundStationConfig(TypedDict, total=False):
    """What a provider configures on a ground station (model field names)."""

    name: str
    lat: float
    lng: float
    alt: float


class GroundStationBusy(RuntimeError):
    """The ground station holds VVs that have not ended, so it cannot go."""

    def __init__(self, station: GroundStation, count: int) -> None:
        super().__init__(f"{station.name} holds {count} VV(s) that have not ended")
        self.station = station
        self.count = count


def _validate_vehicle(vehicle: Vehicle, sensors: Sequence[SensorType] | None = None) -> None:
    """``sensors``: those it is to carry (None: those it carries)."""
    # The database constraint would only say "constraint violated"; name the field instead.
    if (
        vehicle.max_altitude_m is not None
        and vehicle.min_altitude_m is not None
        and vehicle.max_altitude_m < vehicle.min_altitude_m
    ):
        raise ValidationError(
            {"max_altitude_m": f"must not be below min_altitude_m ({vehicle.min_altitude_m:g} m)"}
        )
    vehicle.full_clean()  # field ranges, a unique name, the area, its kind's limits
    carried = sensors if sensors is not None else vehicle.sensors.all() if vehicle.pk else ()
    problem = sensors_not_carried(kind=vehicle.kind, sensors=carried)
    if problem is not None:
        raise ValidationError({"sensors" if sensors is not None else "kind": problem})


def vehicle_set_status(
    *,
    vehicle: Vehicle,
    status: VehicleStatus,
    vvm: VVM,
    reason: str = "",
    expected: VehicleStatus | None = None,
) -> bool:
    """Put an RV into service, into maintenance, or remove it (a person's decisions), or
    take it out of service while it recharges or cannot be flown (the platform's), without
    disturbing customers; ``reason`` says why, for the operator. With ``expected``, only
    from that status: the platform never overrides a person's decision (an RV put into
    maintenance while its link was down stays there when the link returns). Returns whether
    the status changed.

    The VVs aboard an RV that leaves service move to RVs that can serve their tasks, or wait
    on a ground station until one can; VVs waiting on a ground station are looked at again
    whenever an RV comes into service.
    """
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == status or (expected is not None and vehicle.status != expected):
            return False
        vehicle.status = status
        vehicle.status_reason = reason[: Vehicle._meta.get_field("status_reason").max_length]
        vehicle.status_changed = timezone.now()
        vehicle.save(update_fields=["status", "status_reason", "status_changed", "updated"])
        if status != VehicleStatus.ACTIVE:
            aboard = list(
                vehicle.vvs.exclude(status__in=ENDED_STATUSES).values_list("pk", flat=True)
            )
            Task.objects.filter(vehicle=vehicle, status=TaskStatus.OPEN).update(vehicle=None)
            for vv_id in aboard:
                vvm.dispatcher.vv_arrived(vv_id)
        logger.info(
            "vehicle %s: %s",
            vehicle.name,
            status,
            extra={"vehicle": vehicle.name, "status": status, "reason": reason or None},
        )
        vvm.dispatcher.vehicle_changed(vehicle.pk)
    if status == VehicleStatus.ACTIVE:
        vehicle_register(vehicle=vehicle, vvm=vvm)
    return True


class VehicleRemoved(RuntimeError):
    """The RV was removed from the fleet: no command reaches it any more."""

    def __init__(self, vehicle: Vehicle) -> None:
        super().__init__(f"{vehicle.name} was removed from the fleet: it takes no command")
        self.vehicle = vehicle


def vehicle_command(
    *, vehicle: Vehicle, command: VehicleCommand, vvm: VVM, reason: str = ""
) -> Vehicle:
    """An operator's command for an RV (a person's decision): return home now, or land now
    where it is. The RV goes into maintenance at once (``vehicle_set_status``: the VVs aboard
    move on, and the platform sends it out again only once an operator returns it to
    service), and the command waits for the RV's worker, whose control loop takes it exactly
    once (``vehicle_command_take``) and obeys it: a MAVLink autopilot gets its RTL or LAND, a
    simulated vehicle flies home or lands. A newer command replaces one not taken yet.
    ``reason`` says who asked, for the operators. Returns the RV as saved; raises
    VehicleRemoved for a removed RV."""
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        if vehicle.status == VehicleStatus.REMOVED:
            raise VehicleRemoved(vehicle)
        vehicle.command = command
        vehicle.command_requested = timezone.now()
        vehicle.command_taken = None
        vehicle.save(update_fields=["command", "command_requested", "command_taken", "updated"])
        changed = vehicle_set_status(
            vehicle=vehicle, status=VehicleStatus.MAINTENANCE, vvm=vvm, reason=reason
        )
        if not changed:  # in maintenance already: its worker still hears of the command
            vvm.dispatcher.vehicle_changed(vehicle.pk)
        logger.info(
            "vehicle %s: operator's command %s",
            vehicle.name,
            command,
            extra={"vehicle": vehicle.name, "command": str(command), "reason": reason or None},
        )
    vehicle.refresh_from_db()
    return vehicle


def vehicle_command_take(*, vehicle_id: int, command: str, asked: Any) -> bool:
    """The RV's worker takes the operator's command ``command`` asked at ``asked`` (as it
    read them): a fenced UPDATE, so that it is taken once however many loops read it, and
    not at all when a newer command replaced it meanwhile. Returns whether it was taken. (The
    worker's doing, not a person's: not in the audit log.)"""
    taken = Vehicle.objects.filter(
        pk=vehicle_id, command=command, command_requested=asked, command_taken__isnull=True
    ).update(command_taken=timezone.now())
    return bool(taken)


class DutyRefused(Exception):
    """A pilot may not take or hand over this RV: the message says why."""


def vehicle_take_duty(*, vehicles: Sequence[Vehicle], pilot: Any, vvm: VVM) -> list[Vehicle]:
    """``pilot`` takes these RVs on duty (one, or a group at once): they become their pilot
    in command, recorded from now (``PilotDuty``) and in the audit log with every change of
    the RV. All or none: DutyRefused when ``pilot`` is not among an RV's pilots (a superuser
    may take any), when another pilot is on duty for one (they hand it over first), or when
    one was removed. With CPCC_REQUIRE_PILOT, VVs waiting for a pilot are looked at again."""
    now = timezone.now()
    with transaction.atomic():
        held, assigned = _held_with_pilot(vehicles, pilot)
        for vehicle in held:
            if vehicle.status == VehicleStatus.REMOVED:
                raise DutyRefused(f"{vehicle.name} was removed from the fleet.")
            if vehicle.pk not in assigned and not pilot.is_superuser:
                raise DutyRefused(
                    f"You are not one of {vehicle.name}'s pilots: a fleet manager assigns them."
                )
            if vehicle.pilot_on_duty_id not in (None, pilot.pk):
                other = vehicle.pilot_on_duty.get_username()
                raise DutyRefused(
                    f"{other} is on duty for {vehicle.name}: they hand it over to you first."
                )
        for vehicle in held:
            if vehicle.pilot_on_duty_id == pilot.pk:
                continue
            vehicle.pilot_on_duty = pilot
            vehicle.save(update_fields=["pilot_on_duty", "updated"])
            PilotDuty.objects.create(
                vehicle=vehicle, pilot=pilot, pilot_name=pilot.get_username(), started=now
            )
            vvm.dispatcher.vehicle_changed(vehicle.pk)
            logger.info(
                "vehicle %s: %s on duty",
                vehicle.name,
                pilot.get_username(),
                extra={"vehicle": vehicle.name, "pilot": pilot.get_username()},
            )
    vvs_reroute_waiting(vvm=vvm)
    return held


def vehicle_hand_over(
    *, vehicles: Sequence[Vehicle], by: Any, to: Any | None, vvm: VVM
) -> list[Vehicle]:
    """The pilot on duty (``by``; or staff who may change vehicles, for a pilot who left)
    hands these RVs over to another of their pilots (``to``), or to nobody: with
    CPCC_REQUIRE_PILOT an RV with no pilot on duty then takes no new work. All or none:
    DutyRefused when ``by`` is not on duty for one and may not change vehicles, or ``to``
    is not one of its pilots."""
    now = timezone.now()
    with transaction.atomic():
        held, assigned = _held_with_pilot(vehicles, to)
        manager = by.has_perm("fleet.change_vehicle")
        for vehicle in held:
            if vehicle.pilot_on_duty_id != by.pk and not manager:
                raise DutyRefused(f"You are not on duty for {vehicle.name}.")
            if to is not None and vehicle.pk not in assigned and not to.is_superuser:
                raise DutyRefused(f"{to.get_username()} is not one of {vehicle.name}'s pilots.")
        for vehicle in held:
            if vehicle.pilot_on_duty_id == (to.pk if to is not None else None):
                continue
            PilotDuty.objects.filter(vehicle=vehicle, ended__isnull=True).update(
                ended=now, handed_to=to.get_username() if to is not None else ""
            )
            vehicle.pilot_on_duty = to
            vehicle.save(update_fields=["pilot_on_duty", "updated"])
            if to is not None:
                PilotDuty.objects.create(
                    vehicle=vehicle, pilot=to, pilot_name=to.get_username(), started=now
                )
            vvm.dispatcher.vehicle_changed(vehicle.pk)
            logger.info(
                "vehicle %s: handed over to %s",
                vehicle.name,
                to.get_username() if to is not None else "nobody",
                extra={"vehicle": vehicle.name, "by": by.get_username()},
            )
    vvs_reroute_waiting(vvm=vvm)
    return held


def _held_with_pilot(
    vehicles: Sequence[Vehicle], pilot: Any | None
) -> tuple[list[Vehicle], set[int]]:
    """These RVs' rows, held (in id order, as every taker of several holds them), and the ids
    of those ``pilot`` is one of the pilots of (none for no pilot)."""
    held = list(
        Vehicle.objects.select_for_update().filter(pk__in=[v.pk for v in vehicles]).order_by("pk")
    )
    if pilot is None:
        return held, set()
    assigned = Vehicle.pilots.through.objects.filter(
        vehicle_id__in=[v.pk for v in held], user_id=pilot.pk
    ).values_list("vehicle_id", flat=True)
    return held, set(assigned)


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
        newcomer = vehicle_caps(vehicle)
        if not newcomer.active:  # (out of service, or with no pilot on duty where one is due)
            return
        fleet = {c.id: c for c in fleet_caps(vvm)}
        if vehicle.pk in fleet:  # where it is now (its host may know better than its row)
            newcomer = dataclasses.replace(newcomer, position=fleet[vehicle.pk].position)
        aboard_others = (
            VirtualVehicle.objects.select_for_update(of=("self",), no_key=True)
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
            vv_release_tasks(vv=vv, vvm=vvm)
            vv_record_migration(
                vv=vv, to=vehicle, reason="a closer vehicle came into service", vvm=vvm
            )
            vv.status = VVStatus.MIGRATING
            vv.save(update_fields=["host_rv", "host_gs", "status", "updated"])
            vvm.dispatcher.vv_arrived(vv.pk)
            newcomer = dataclasses.replace(newcomer, open_tasks=newcomer.open_tasks + len(tasks))
    vvm.dispatcher.vehicle_changed(vehicle.pk)


def vehicle_record_health(*, vehicle_id: int, health: dict[str, Any]) -> bool:
    """What the RV's worker sees of the vehicle's health now (link, battery, armed, mode,
    fence), for the operator: kept with the time it changed, and its battery's charge
    (``battery_observe``: cycles, lowest charge, a swap). Health never changes the status a
    person set. Returns whether the RV's maintenance must be looked at again (a battery put in
    or retired: ``vehicle_check_maintenance``)."""
    Vehicle.objects.filter(pk=vehicle_id).update(health=health, health_changed=timezone.now())
    return battery_observe(
        vehicle_id=vehicle_id,
        pct=health.get("battery_pct"),
        battery_id=health.get("battery_id"),
        serial=health.get("battery_serial"),
        now=timezone.now(),
    )


def vehicles_worker_stopped(*, vehicle_ids: Sequence[int]) -> None:
    """The worker of these RVs stopped cleanly: their health says so until a worker reports
    again (what the link and the battery were is not known any more)."""
    Vehicle.objects.filter(pk__in=vehicle_ids).update(
        health={"worker": "stopped"}, health_changed=timezone.now()
    )


def vehicle_heartbeat(*, vehicle_id: int, vvm: VVM) -> None:
    """The vehicle's worker is alive (it renews its lease). The time is the database's: a
    worker whose clock is behind or ahead renews its lease all the same (``online_vehicles``
    reads the same clock)."""
    Vehicle.objects.filter(pk=vehicle_id).update(worker_seen=Now())


class LeasesUnsure(Exception):
    """The leases cannot be judged now: the database kept the checker (and so the heartbeats)
    waiting. The caller gives every RV a full lease before it looks again."""


def vehicles_check_leases(*, vvm: VVM) -> list[str]:
    """Move the VVs off every RV whose worker has stopped reporting; returns those RVs' names.

    The VVs wait on a ground station, which routes them to an RV that can serve them (this
    one again, if its worker comes back). Whatever that worker might still report for their
    tasks is refused (``task_complete`` checks the vehicle), so no reading is taken twice.
    """
    assert vvm.lease_s is not None
    gone = []
    asked = time.monotonic()
    # One transaction, taken before the leases are read, every time: with SQLite it waits
    # for the write lock, which also kept the workers' heartbeats waiting. Having waited long,
    # the check judges no lease (LeasesUnsure); a lock that outlasts SQLite's timeout is an
    # outage (OperationalError), after which the caller gives every RV a full lease too.
    with transaction.atomic():
        online = online_vehicles(vvm).values("pk")
        stale = list(
            Vehicle.objects.exclude(pk__in=online)
            .filter(vvs__status__in=ACTIVE_STATUSES)
            .distinct()
        )
        if time.monotonic() - asked > vvm.lease_s / 4:
            raise LeasesUnsure(", ".join(v.name for v in stale))
        for vehicle in stale:
            stranded = (
                VirtualVehicle.objects.select_for_update(of=("self",), no_key=True)
                .filter(host_rv=vehicle, status__in=ACTIVE_STATUSES)
                .select_related("customer", "host_gs", "host_rv")
            )
            for vv in stranded:
                vv_migrate_to_ground_station(
                    vv=vv, reason="its vehicle's worker stopped reporting", vvm=vvm
                )
                vv.save()
            gone.append(vehicle.name)
    for name in gone:
        logger.warning("vehicle %s: its worker is gone", name, extra={"vehicle": name})
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


def no_fly_zone_save(*, zone: NoFlyZone, vvm: VVM) -> NoFlyZone:
    """Add or change a no-fly zone. The tasks planned on every RV are routed again (a task
    now inside the zone ends rejected with the reason, as any task no RV may serve), and each
    RV's worker gives its autopilot the zones anew. Raises ValidationError naming the field
    (an area that is not a closed ring, altitudes upside down, a name in use)."""
    with transaction.atomic():
        zone.full_clean()
        zone.save()
    _airspace_changed(vvm=vvm, reroute=True)
    return zone


def no_fly_zone_delete(*, zone: NoFlyZone, vvm: VVM) -> None:
    """Remove a no-fly zone: the RVs may serve tasks there again."""
    zone.delete()
    _airspace_changed(vvm=vvm, reroute=True)


def rally_point_save(*, point: RallyPoint, vvm: VVM) -> RallyPoint:
    """Add or change a rally point: each RV's worker gives its autopilot the rally points
    anew. Raises ValidationError naming the field."""
    with transaction.atomic():
        point.full_clean()
        point.save()
    _airspace_changed(vvm=vvm, reroute=False)
    return point


def rally_point_delete(*, point: RallyPoint, vvm: VVM) -> None:
    point.delete()
    _airspace_changed(vvm=vvm, reroute=False)


def _airspace_changed(*, vvm: VVM, reroute: bool) -> None:
    """The no-fly zones or rally points changed: each RV's worker hears of it (and uploads
    its autopilot's fence again); with ``reroute`` the tasks planned on the RVs are routed
    again too."""
    vehicles = Vehicle.objects.exclude(status=VehicleStatus.REMOVED)
    if reroute:
        for vehicle in vehicles:
            vehicle_reconfigured(vehicle=vehicle, vvm=vvm)
        return
    with transaction.atomic():  # the messages go once it commits
        for vehicle_id in vehicles.values_list("pk", flat=True):
            vvm.dispatcher.vehicle_changed(vehicle_id)


def vehicle_create(*, config: VehicleConfig, sensors: Sequence[str], vvm: VVM) -> Vehicle:
    """Add an RV to the fleet, in service: it takes work at once (``vehicle_register``).

    Raises ValidationError naming the field: a bad area (not closed, fewer than 3 points,
    crossing itself), an altitude range upside down, a name in use, unknown sensor names.
    """
    entries = sensor_entries(sensors, field="sensors")
    with transaction.atomic():
        vehicle = Vehicle(**config)
        _validate_vehicle(vehicle, entries)
        vehicle.save()
        vehicle.sensors.set(entries)
    vehicle_register(vehicle=vehicle, vvm=vvm)
    return vehicle


def vehicle_update(
    *, vehicle: Vehicle, config: VehicleConfig, sensors: Sequence[str] | None, vvm: VVM
) -> Vehicle:
    """Change an RV's configuration; ``sensors`` None keeps its sensors.

    When its reach changes (area, altitude range, sensors), the tasks planned on it are taken
    off it and the VVs aboard route them again: they stay if it can still serve them and move
    to an RV that can otherwise; an RV in service with a larger reach takes work at once.
    Raises ValidationError naming the field, like ``vehicle_create``.
    """
    entries = None if sensors is None else sensor_entries(sensors, field="sensors")
    reach_changed = entries is not None or any(f in config for f in REACH_FIELDS)
    with transaction.atomic():
        vehicle = Vehicle.objects.select_for_update().get(pk=vehicle.pk)
        for name, value in config.items():
            setattr(vehicle, name, value)
        _validate_vehicle(vehicle, entries)
        vehicle.save()
        if entries is not None:
            vehicle.sensors.set(entries)
        if "sensor_sources" in config and not reach_changed:
            vvm.dispatcher.vehicle_changed(vehicle.pk)  # its worker reads them from now on
    if reach_changed:
        vehicle_reconfigured(vehicle=vehicle, vvm=vvm)
    return vehicle


def ground_station_create(*, config: GroundStationConfig, vvm: VVM) -> GroundStation:
    """Add a ground station. VVs waiting in a queue because there was none start now.

    Raises ValidationError naming the field (position out of range, name in use).
    """
    with transaction.atomic():
        station = GroundStation(**config)
        station.full_clean()
        station.save()
        waiting = (
            VirtualVehicle.objects.filter(status=VVStatus.QUEUED)
            .values_list("customer_id", flat=True)
            .distinct()
        )
        for customer_id in sorted(waiting):
            vvm.dispatcher.customer_slot_freed(customer_id)
    return station


def ground_station_update(*, station: GroundStation, config: GroundStationConfig) -> GroundStation:
    """Rename or move a ground station. Raises ValidationError naming the field."""
    with transaction.atomic():
        station = GroundStation.objects.select_for_update().get(pk=station.pk)
        for name, value in config.items():
            setattr(station, name, value)
        station.full_clean()
        station.save()
    return station


def ground_station_delete(*, station: GroundStation) -> None:
    """Remove a ground station; GroundStationBusy while it holds VVs that have not ended."""
    with transaction.atomic():
        station = GroundStation.objects.select_for_update().get(pk=station.pk)
        busy = station.vvs.exclude(status__in=ENDED_STATUSES).count()
        if busy:
            raise GroundStationBusy(station, busy)
        station.delete()


def vehicle_record_state(
    *,
    vehicle_id: int,
    state: VehicleState,
    track_aboard: bool = False,
    tasks_done: int = 0,
    take_offs: Sequence[TakeOffRow] = (),
    landings: Sequence[LandingRow] = (),
) -> None:
    """What an RV's control loop reports of its vehicle (``state``): where it is at its time,
    its flight phase, its odometer and flight time, and the planner's state (kept for a
    restarted worker); ``track_aboard``: every VV aboard now gets this point on its track
    (found by the database in the same statement); ``tasks_done``: the RV served that many
    more tasks; ``take_offs`` and ``landings``: its flights began and ended then
    (``vehicle_record_flights``), in the same commit. Inside the caller's transaction when
    there is one."""
    here = state.position
    values = {
        "lat": here.lat,
        "lng": here.lng,
        "alt": here.alt,
        "phase": state.phase,
        "distance_m": state.distance_m,
        "flight_s": state.flight_s,
        "planner_state": state.planner_state,
    }
    add = {"tasks_done": tasks_done} if tasks_done else None
    track_point = (state.t_s, here) if track_aboard else None
    vehicle_report(
        vehicle_id,
        values=values,
        add=add,
        track_point=track_point,
        take_offs=take_offs,
        landings=landings,
    )


def vehicle_record_flights(
    *,
    vehicle_id: int,
    take_offs: Sequence[TakeOffRow] = (),
    landings: Sequence[LandingRow] = (),
) -> None:
    """The RV's flights as its loop reported them, written with the loop's next report, in
    the caller's transaction (or in a commit of its own). A take-off opens a ``Flight`` with
    the pilot on duty for it (none: empty) as the database has it then, and the RV's
    odometers at the take-off; a landing closes the flight of its take-off (none open, a
    vehicle that started in the air: nothing) with its end, how it ended, its duration and
    distance (what the odometers gained), highest altitude, battery at both ends, and the
    tasks the RV answered done during it with their customers and VVs."""
    flights_write(vehicle_id, take_offs=take_offs, landings=landings)


def vehicle_record_track(*, vehicle_id: int, points: Sequence[tuple[float, Position]]) -> None:
    """Points (time, position) on the track of every VV aboard the RV now: the ends of the
    legs it flew since it last wrote them, in order. Inside the caller's transaction, which is
    about to change who is aboard."""
    if points:
        track_points_aboard(vehicle_id, points)
