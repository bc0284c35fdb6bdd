"""Scenarios: putting a scenario's catalog additions, ground stations, vehicles and customers
into the database (idempotent), submitting its VVs, applying its fleet events; and what a demo
does before it starts."""

from __future__ import annotations

import hashlib
import secrets
import uuid
from collections.abc import Callable
from dataclasses import dataclass, field

from django.db import transaction
from django.utils.text import slugify

from accounts.models import Customer, User
from fleet.models import GroundStation, NoFlyZone, SensorType, Vehicle, VehicleStatus
from missions.models import (
    ACTIVE_STATUSES,
    Task,
    TaskStatus,
    VirtualVehicle,
    VVStatus,
    vv_name_problem,
)
from vvm_worker.scenario import (
    CustomerSpec,
    FleetEvent,
    Scenario,
    ScenarioError,
    VehicleSpec,
    VVSpec,
    vv_instances,
)
from vvm_worker.services.admission import vv_submit
from vvm_worker.services.base import VVM
from vvm_worker.services.customers import service_class_save
from vvm_worker.services.fleet import vehicle_register, vehicle_set_status


@dataclass
class LoadedScenario:
    """What a scenario put into the database; ``logins`` holds (username, password or None
    when an existing user kept its password)."""

    customers: dict[str, Customer] = field(default_factory=dict)
    vehicles: dict[str, Vehicle] = field(default_factory=dict)
    ground_stations: dict[str, GroundStation] = field(default_factory=dict)
    logins: list[tuple[str, str | None]] = field(default_factory=list)


def _check_vv_names(scenario: Scenario) -> None:
    """A VV name the submission would refuse (vv_submit), said with its place in the file
    before anything is loaded."""
    for i, spec in enumerate(scenario.vvs):
        problem = vv_name_problem(spec.name)
        if problem is not None:
            raise ScenarioError(
                f"vvs[{i}].name", problem, file=str(scenario.path) if scenario.path else None
            )


def _check_sensors(scenario: Scenario) -> None:
    """Every vehicle sensor is in the SDC (the scenario's entries already put there) and
    carried by the vehicle's kind."""
    carriers = {s.name: s for s in SensorType.objects.all()}
    known = set(carriers) | {s.name for s in scenario.sensors}
    specs = [(f"vehicles[{i}]", v) for i, v in enumerate(scenario.vehicles)]
    specs += [
        (f"events[{i}].add_vehicle", e.add_vehicle)
        for i, e in enumerate(scenario.events)
        if e.add_vehicle is not None
    ]
    for path, spec in specs:
        for k, name in enumerate(spec.sensors):
            if name not in known:
                raise ScenarioError(
                    f"{path}.sensors[{k}]",
                    f"unknown SDC entry {name!r} (known: {', '.join(sorted(known))})",
                    file=str(scenario.path) if scenario.path else None,
                )
            entry = carriers.get(name)
            if entry is not None and not entry.carried_by(spec.kind):
                raise ScenarioError(
                    f"{path}.sensors[{k}]",
                    f"vehicle {spec.name!r} is {spec.kind}: it cannot carry SDC entry {name!r} "
                    f"(carried by {', '.join(entry.kinds)} vehicles only)",
                    file=str(scenario.path) if scenario.path else None,
                )


def vehicle_upsert(*, spec: VehicleSpec) -> Vehicle:
    """Create or update an RV from its scenario description (in service, at its depot)."""
    vehicle, _ = Vehicle.objects.update_or_create(
        name=spec.name,
        defaults={
            "status": VehicleStatus.ACTIVE,
            "driver": spec.driver,
            "driver_url": spec.driver_url or "",
            "depot_lat": spec.depot.lat,
            "depot_lng": spec.depot.lng,
            "depot_alt": spec.depot.alt,
            "area": [list(p) for p in spec.area],
            "min_altitude_m": spec.min_altitude_m,
            "max_altitude_m": spec.max_altitude_m,
            "max_speed_mps": spec.max_speed_mps,
            "climb_rate_mps": spec.climb_rate_mps or 3.0,
            "kind": spec.kind,
            "dive_rate_mps": spec.dive_rate_mps,
            "turn_rate_dps": spec.turn_rate_dps,
            "battery_s": spec.battery_s,
            "lat": spec.depot.lat,
            "lng": spec.depot.lng,
            "alt": spec.depot.alt,
            "phase": "landed",
        },
    )
    vehicle.sensors.set(SensorType.objects.filter(name__in=spec.sensors))
    return vehicle


def _customer_upsert(spec: CustomerSpec) -> Customer:
    quotas: dict[str, object] = {"privileged": spec.privileged}
    for name in Customer.QUOTA_FIELDS:  # a quota the scenario leaves out keeps its default
        value = getattr(spec, name)
        if value is not None:
            quotas[name] = value
    if spec.service_class is not None:  # a class the scenario leaves out keeps the customer's
        quotas["service_class"] = service_class_save(
            name=spec.service_class.name,
            p95_s=spec.service_class.p95_s or 0.0,
            weight=spec.service_class.weight,
        )
    customer, _ = Customer.objects.update_or_create(
        name=spec.name, defaults={"slug": slugify(spec.name), **quotas}
    )
    return customer


def _login_for(customer: Customer, password: str | None) -> tuple[str, str | None]:
    username = customer.slug
    user = User.objects.filter(username=username).first()
    if user is None:
        password = password or secrets.token_urlsafe(9)
        user = User(username=username, customer=customer)
        user.set_password(password)
        user.save()
        return username, password
    user.customer = customer
    if password is not None:
        user.set_password(password)
    user.save()
    return username, password


def scenario_apply(
    *, scenario: Scenario, logins: bool = True, password: str | None = None
) -> LoadedScenario:
    """Put the scenario's SDC additions, ground stations, RVs, no-fly zones and customers
    (with a login user each, unless ``logins`` is False) into the database. Running it twice
    changes nothing the second time. A customer's login gets ``password``; without one, a new
    login gets a generated password and an existing one keeps its own (``logins`` says
    which).

    Raises ScenarioError for a vehicle sensor that is in neither the SDC nor the scenario,
    or that the vehicle's kind cannot carry (``SensorType.kinds``), and for a VV's name with
    a control or bidirectional formatting character (which ``vv_submit`` would refuse).
    """
    loaded = LoadedScenario()
    with transaction.atomic():
        for entry in scenario.sensors:
            SensorType.objects.update_or_create(
                name=entry.name,
                defaults={
                    "kind": entry.kind,
                    "unit": entry.unit,
                    "params": dict(entry.params),
                    "privileged": entry.privileged,
                    "description": entry.description or entry.name,
                    "kinds": list(entry.kinds),
                },
            )
        _check_sensors(scenario)
        _check_vv_names(scenario)
        for gs in scenario.ground_stations:
            loaded.ground_stations[gs.name], _ = GroundStation.objects.update_or_create(
                name=gs.name,
                defaults={"lat": gs.position.lat, "lng": gs.position.lng, "alt": gs.position.alt},
            )
        for spec in scenario.vehicles:
            loaded.vehicles[spec.name] = vehicle_upsert(spec=spec)
        for zone in scenario.no_fly_zones:
            NoFlyZone.objects.update_or_create(
                name=zone.name,
                defaults={
                    "area": [list(point) for point in zone.area],
                    "min_altitude_m": zone.min_altitude_m,
                    "max_altitude_m": zone.max_altitude_m,
                },
            )
        for customer_spec in scenario.customers:
            customer = _customer_upsert(customer_spec)
            loaded.customers[customer_spec.name] = customer
            if logins:  # a password costs a third of a second to hash, on purpose
                loaded.logins.append(_login_for(customer, password))
    return loaded


def derived_seed(seed: int, *parts: str) -> int:
    """A 31-bit seed from the run's seed and names, the same on every run."""
    digest = hashlib.sha256(":".join([str(seed), *parts]).encode()).digest()
    return int.from_bytes(digest[:4], "big") & 0x7FFFFFFF


def derived_uuid(seed: int, *parts: str) -> uuid.UUID:
    digest = hashlib.sha256(":".join(["vv", str(seed), *parts]).encode()).digest()
    return uuid.UUID(bytes=digest[:16], version=4)


def scenario_submit_vv(
    *,
    spec: VVSpec,
    instance_name: str,
    customer: Customer,
    vvm: VVM,
    seed: int | None = None,
    admit: bool = True,
) -> VirtualVehicle:
    """Submit one VV of a scenario; a syntax error lets it end ``failed`` when it is loaded."""
    vv_seed = None if seed is None else derived_seed(seed, customer.name, instance_name)
    vv_id = None if seed is None else derived_uuid(seed, customer.name, instance_name)
    return vv_submit(
        customer=customer,
        name=instance_name,
        program=spec.source,
        vvm=vvm,
        seed=vv_seed,
        vv_id=vv_id,
        refuse_syntax_errors=False,
        admit=admit,
    )


def scenario_submit_all(
    *, scenario: Scenario, loaded: LoadedScenario, vvm: VVM, admit: bool = True
) -> list[VirtualVehicle]:
    """Submit every VV of the scenario now (``submit_at_s`` is for ``simulate``)."""
    return [
        scenario_submit_vv(
            spec=spec,
            instance_name=name,
            customer=loaded.customers[spec.customer],
            vvm=vvm,
            admit=admit,
        )
        for spec, name in vv_instances(scenario)
    ]


EVENT_STATUS = {
    "remove": VehicleStatus.REMOVED,
    "maintenance": VehicleStatus.MAINTENANCE,
    "return": VehicleStatus.ACTIVE,
}


def scenario_event_apply(
    *, event: FleetEvent, vvm: VVM, on_added: Callable[[Vehicle], None] | None = None
) -> Vehicle:
    """Apply one fleet event of a scenario; returns the vehicle it concerns.

    An added vehicle gets its control loop or worker from ``on_added`` before it is given work.
    """
    if event.add_vehicle is not None:
        vehicle = vehicle_upsert(spec=event.add_vehicle)
        if on_added is not None:
            on_added(vehicle)
        vehicle_register(vehicle=vehicle, vvm=vvm)
        return vehicle
    vehicle = Vehicle.objects.get(name=event.vehicle)
    vehicle_set_status(
        vehicle=vehicle,
        status=EVENT_STATUS[event.action],
        vvm=vvm,
        reason=f"the scenario's event at {event.at_s:g} s",
    )
    return vehicle


def demo_reset(*, reason: str) -> None:
    """Start a demo afresh on a database an interrupted one left behind: its unfinished VVs
    are cancelled (with ``reason``), their open tasks dropped, and every vehicle stands
    landed at its depot."""
    with transaction.atomic():
        VirtualVehicle.objects.filter(status__in=(VVStatus.QUEUED, *ACTIVE_STATUSES)).update(
            status=VVStatus.CANCELLED, host_rv=None, pending=None, error=reason
        )
        Task.objects.filter(status=TaskStatus.OPEN).update(
            status=TaskStatus.CANCELLED, vehicle=None
        )
        for vehicle in Vehicle.objects.all():
            Vehicle.objects.filter(pk=vehicle.pk).update(
                lat=vehicle.depot_lat, lng=vehicle.depot_lng, alt=vehicle.depot_alt, phase="landed"
            )
