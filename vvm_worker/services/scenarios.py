"""Scenarios: putting a scenario's catalog additions, ground stations, vehicles and customers
into the database (idempotent), submitting its VVs, applying its fleet events; and what a demo
does before it starts."""

from __future__ import annotations

import hashlib
import secrets
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from django.contrib.auth.hashers import make_password
from django.contrib.auth.models import Group
from django.core.exceptions import ValidationError
from django.core.validators import validate_email
from django.db import transaction
from django.utils.text import slugify

from accounts.models import Customer, User
from accounts.roles import PILOT, VIEWER
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
    MemberSpec,
    Scenario,
    ScenarioError,
    StaffSpec,
    VehicleSpec,
    VVSpec,
    vv_instances,
)
from vvm_worker.services.admission import vv_submit
from vvm_worker.services.base import VVM
from vvm_worker.services.customers import service_class_save, user_set_login
from vvm_worker.services.fleet import vehicle_register, vehicle_set_status


@dataclass
class LoadedScenario:
    """What a scenario put into the database; ``logins`` holds (username, password or None
    when an existing user kept its password), and ``labels`` says who each login is that is
    not a customer's own: a member's customer and role (``"Customer A, viewer"``), a staff
    user's groups (``"pilot"``)."""

    customers: dict[str, Customer] = field(default_factory=dict)
    vehicles: dict[str, Vehicle] = field(default_factory=dict)
    ground_stations: dict[str, GroundStation] = field(default_factory=dict)
    logins: list[tuple[str, str | None]] = field(default_factory=list)
    # The customers' users the scenario names (besides their own logins) and its staff.
    members: dict[str, User] = field(default_factory=dict)
    staff: dict[str, User] = field(default_factory=dict)
    labels: dict[str, str] = field(default_factory=dict)


class _Passwords:
    """The passwords a scenario gives its logins: ``password`` to every one (hashed once: the
    hasher is slow on purpose, and a team of users would cost a third of a second each);
    without it a generated one to each new user, while an existing user keeps its own. With
    ``logins`` off, a new user gets no usable password (nobody logs in to a simulation)."""

    def __init__(self, password: str | None, *, logins: bool) -> None:
        self.password = password
        self.logins = logins
        self.hashed: str | None = None

    def give(self, user: User, *, new: bool) -> str | None:
        """Set the user's password (not saved); returns it, or None when it kept its own."""
        if not self.logins:
            if new:
                user.set_unusable_password()
            return None
        if self.password is None:
            if not new:
                return None
            password = secrets.token_urlsafe(9)
            user.set_password(password)
            return password
        if self.hashed is None:
            self.hashed = make_password(self.password)
        user.password = self.hashed
        return self.password


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


def _check_people(scenario: Scenario) -> None:
    """The users and staff a scenario names are not someone else in the database (another
    customer's user, staff for a customer's user or the other way round, a customer's own
    login), their e-mail addresses are addresses, their groups are there, and every pilot it
    does not name itself is staff in the database."""
    file = str(scenario.path) if scenario.path else None
    own_logins = {slugify(c.name): (i, c.name) for i, c in enumerate(scenario.customers)}
    people: list[tuple[str, str, str | None, str | None]] = [
        (f"customers[{i}].users[{k}]", user.name, customer.name, user.email)
        for i, customer in enumerate(scenario.customers)
        for k, user in enumerate(customer.users)
    ]
    people += [
        (f"staff[{i}]", user.name, None, user.email) for i, user in enumerate(scenario.staff)
    ]
    existing = {
        user.username: user
        for user in User.objects.filter(username__in=[p[1] for p in people]).select_related(
            "customer"
        )
    }
    for path, name, customer_name, email in people:
        if name in own_logins:
            i, owner = own_logins[name]
            raise ScenarioError(
                f"{path}.name",
                f"{name!r} is the login of customer {owner!r} (customers[{i}]), which every "
                "customer gets as its owner: choose another name",
                file=file,
            )
        user = existing.get(name)
        if user is not None:
            theirs = user.customer.name if user.customer is not None else None
            if theirs != customer_name:
                if theirs is not None:
                    what = f"a user of customer {theirs!r}"
                else:
                    what = "staff" if user.is_staff else "a user of no customer"
                wanted = f"a user of customer {customer_name!r}" if customer_name else "staff"
                raise ScenarioError(
                    f"{path}.name",
                    f"{name!r} is {what} in the database, so it cannot be {wanted}: "
                    "choose another name",
                    file=file,
                )
        if email is not None:
            try:
                validate_email(email)
            except ValidationError:
                raise ScenarioError(
                    f"{path}.email", f"{email!r} is not an e-mail address", file=file
                ) from None
    groups = {group for user in scenario.staff for group in user.groups}
    missing = groups - set(Group.objects.filter(name__in=groups).values_list("name", flat=True))
    if missing:
        raise ScenarioError(
            "staff",
            f"the staff group(s) {', '.join(sorted(missing))} are not in the database: "
            "run manage.py migrate",
            file=file,
        )
    names = [name for _, name in scenario.outside_pilots]
    staff = set(
        User.objects.filter(username__in=names, is_staff=True).values_list("username", flat=True)
    )
    for place, name in scenario.outside_pilots:
        if name not in staff:
            raise ScenarioError(
                place,
                f"no staff user {name!r}: a pilot is one of the scenario's staff or a staff "
                "user in the database",
                file=file,
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
    if spec.pilots is not None:  # left out: the pilots an administrator gave it stay
        vehicle.pilots.set(User.objects.filter(username__in=spec.pilots, is_staff=True))
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


def _login_for(customer: Customer, passwords: _Passwords) -> tuple[str, str | None]:
    username = customer.slug
    user = User.objects.filter(username=username).first()
    new = user is None
    if user is None:
        user = User(username=username)
    user.customer = customer
    password = passwords.give(user, new=new)
    user.save()
    return username, password


def _member_upsert(
    spec: MemberSpec, customer: Customer, passwords: _Passwords
) -> tuple[User, str | None]:
    """A user of ``customer`` with the scenario's role (``_check_people`` made sure the name
    is no one else's), and the password it was given (None: it kept its own)."""
    user = User.objects.filter(username=spec.name).first()
    new = user is None
    if user is None:
        user = User(username=spec.name)
    user.customer, user.role = customer, spec.role
    if spec.email is not None:
        user.email = spec.email
    password = passwords.give(user, new=new)
    user.save()
    return user, password


def _staff_upsert(spec: StaffSpec, passwords: _Passwords) -> tuple[User, str | None]:
    """A staff user in exactly the scenario's groups (a superuser stays one), and the password
    it was given (None: it kept its own)."""
    user = User.objects.filter(username=spec.name).first()
    new = user is None
    if user is None:
        user = User(username=spec.name)
    user.is_staff = True
    if spec.email is not None:
        user.email = spec.email
    password = passwords.give(user, new=new)
    user.save()
    user.groups.set(Group.objects.filter(name__in=spec.groups))
    return user, password


def scenario_apply(
    *, scenario: Scenario, logins: bool = True, password: str | None = None
) -> LoadedScenario:
    """Put the scenario's SDC additions, ground stations, staff (in their groups), RVs (with
    their pilots), no-fly zones and customers (with a login user each, an owner, unless
    ``logins`` is False; and the users it names, with their roles) into the database. Running
    it twice changes nothing the second time. Every login gets ``password``; without one, a
    new login gets a generated password and an existing one keeps its own (``logins`` says
    which). Without ``logins``, the customers get no login of their own and the users and
    staff the scenario names no usable password.

    Raises ScenarioError for a vehicle sensor that is in neither the SDC nor the scenario,
    or that the vehicle's kind cannot carry (``SensorType.kinds``), for a VV's name with
    a control or bidirectional formatting character (which ``vv_submit`` would refuse), for
    a user or staff name that is someone else's in the database (``_check_people``), and for
    a pilot that is neither the scenario's staff nor staff in the database.
    """
    loaded = LoadedScenario()
    passwords = _Passwords(password, logins=logins)
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
        _check_people(scenario)
        staff_logins = []
        for staff_spec in scenario.staff:  # before the vehicles they fly
            user, given = _staff_upsert(staff_spec, passwords)
            loaded.staff[staff_spec.name] = user
            loaded.labels[staff_spec.name] = ", ".join(staff_spec.groups) or "in no group"
            staff_logins.append((staff_spec.name, given))
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
            if logins:
                loaded.logins.append(_login_for(customer, passwords))
            for member in customer_spec.users:
                user, given = _member_upsert(member, customer, passwords)
                loaded.members[member.name] = user
                loaded.labels[member.name] = f"{customer.name}, {member.role}"
                if logins:
                    loaded.logins.append((member.name, given))
        if logins:
            loaded.logins += staff_logins
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


DEMO_PILOT = "pilot"


def demo_people(
    *, customer: Customer | None, vehicles: Sequence[Vehicle], password: str
) -> tuple[User | None, User]:
    """The demo's people to try the roles with, each with ``password``: a viewer of
    ``customer`` (``<slug>-viewer``: reads everything of the customer, changes nothing; None
    without a customer), and a pilot (``pilot``: staff in the pilot group, one of the pilots
    of ``vehicles``). The pilot is not put on duty: the demo's RVs need none
    (CPCC_REQUIRE_PILOT is off), and a pilot who tries takes them on duty through the API."""
    with transaction.atomic():
        viewer = None
        if customer is not None:
            viewer = user_set_login(
                username=f"{customer.slug}-viewer",
                password=password,
                customer=customer,
                role=VIEWER,
            )
        pilot = user_set_login(username=DEMO_PILOT, password=password, groups=[PILOT])
        for vehicle in vehicles:
            vehicle.pilots.add(pilot)
    return viewer, pilot


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
