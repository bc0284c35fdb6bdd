"""Scenario files: parse and validate the JSON contract of DESIGN.md section 5.

Pure Python (no Django). A scenario describes ground stations, vehicles, customers, the VVs
they submit, optional SDC additions and optional fleet events. `load_scenario` reads a file,
`parse_scenario` checks already-decoded JSON; both return a frozen `Scenario` or raise the
first problem found as a `ScenarioError` that names the place (`vehicles[1].area`) and, when
known, the file. Nothing here touches the database: sensor names given to vehicles are only
checked to be non-empty strings, because the catalog they refer to is the database's SDC plus
the scenario's own `sensors`, which the loader knows (it also checks that a vehicle's kind can
carry each of its sensors). Likewise a vehicle's `pilots` that are not the scenario's own
`staff` are looked for among the database's staff by the loader.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any, Final

from shapely.geometry import Polygon
from shapely.validation import explain_validity

from fleet.geo import Position
from fleet.kinds import (
    AERIAL,
    DEFAULT_KIND,
    GROUND,
    KINDS,
    SURFACE,
    UNDERWATER,
    limit_problems,
)
from vvm_worker.level_figures import ServiceClassSpec

__all__ = [
    "CustomerSpec",
    "FleetEvent",
    "GroundStationSpec",
    "MemberSpec",
    "NoFlyZoneSpec",
    "Scenario",
    "ScenarioError",
    "SensorSpecEntry",
    "StaffSpec",
    "VVSpec",
    "VehicleSpec",
    "load_scenario",
    "parse_scenario",
    "vv_instances",
]

DRIVERS: Final = ("sim", "mavlink")
SENSOR_KINDS: Final = ("scalar", "gps", "camera")
VEHICLE_ACTIONS: Final = ("remove", "maintenance", "return")
ADD_ACTION: Final = "add"
# The roles of a customer's users and the staff groups, as accounts.roles names them (a pure
# core imports no app: tests/vvm_worker/test_scenario_roles.py checks that they agree).
MEMBER_ROLES: Final = ("owner", "developer", "viewer")
DEFAULT_ROLE: Final = "owner"  # as a customer's login has been since before roles
STAFF_GROUPS: Final = ("fleet manager", "pilot", "support")


class ScenarioError(ValueError):
    """What is wrong in a scenario and where.

    `path` locates the value inside the document (`"vehicles[1].area"`, `"vvs[0].program"`;
    `""` for the document itself), `message` says what is wrong, `file` is the scenario file
    when known. `line` and `column` are set (1-based) for JSON syntax errors only.
    `str(err)` is `"FILE: PATH: MESSAGE"`, leaving out the parts that are unknown or empty.
    """

    def __init__(
        self,
        path: str,
        message: str,
        *,
        file: str | None = None,
        line: int | None = None,
        column: int | None = None,
    ) -> None:
        self.path = path
        self.message = message
        self.file = file
        self.line = line
        self.column = column
        super().__init__(self._text())

    def _text(self) -> str:
        parts = [part for part in (self.file, self.path) if part]
        return ": ".join([*parts, self.message])

    def __str__(self) -> str:
        return self._text()

    def __reduce__(self) -> tuple[Any, ...]:
        # Keyword-only fields would be lost by ValueError's pickling (Celery pickles errors).
        return (_rebuild_error, (self.path, self.message, self.file, self.line, self.column))

    def in_file(self, file: str | None) -> ScenarioError:
        """The same error attributed to `file` (unchanged when `file` is None)."""
        if file is None:
            return self
        return ScenarioError(self.path, self.message, file=file, line=self.line, column=self.column)


def _rebuild_error(
    path: str, message: str, file: str | None, line: int | None, column: int | None
) -> ScenarioError:
    return ScenarioError(path, message, file=file, line=line, column=column)


@dataclass(frozen=True)
class GroundStationSpec:
    """A ground station: where VVs are loaded and where they return."""

    name: str
    position: Position


@dataclass(frozen=True)
class VehicleSpec:
    """A real vehicle, its operation area (closed ring of (lat, lng), first == last) and limits."""

    name: str
    depot: Position
    area: tuple[tuple[float, float], ...]
    min_altitude_m: float
    max_altitude_m: float
    max_speed_mps: float
    sensors: tuple[str, ...]
    driver: str = "sim"
    battery_s: float | None = None
    climb_rate_mps: float | None = None
    driver_url: str | None = None
    # How it moves (fleet.kinds); below 0 m is depth, which only an underwater vehicle reaches.
    kind: str = DEFAULT_KIND
    dive_rate_mps: float | None = None  # underwater: how fast it dives (None: its climb rate)
    turn_rate_dps: float | None = None  # ground and surface: how fast it turns (None: default)
    # Where a simulated aerial vehicle is when the scenario starts, in the air (above its
    # depot): it starts there, hovering. None: landed at its depot.
    start: Position | None = None
    # The user names of the staff who may fly it (the scenario's `staff` or the database's);
    # None: the scenario says nothing of them (a vehicle already there keeps its pilots).
    pilots: tuple[str, ...] | None = None


@dataclass(frozen=True)
class NoFlyZoneSpec:
    """A no-fly zone (closed ring of (lat, lng)) between two altitudes (None: no ceiling)."""

    name: str
    area: tuple[tuple[float, float], ...]
    min_altitude_m: float = 0.0
    max_altitude_m: float | None = None


@dataclass(frozen=True)
class CustomerSpec:
    """A customer (tenant) and its quotas; a quota left as None keeps the platform default."""

    name: str
    max_parallel_vvs: int
    privileged: bool = False
    max_queued_vvs: int | None = None
    max_tasks_per_vv: int | None = None
    storage_bytes: int | None = None
    cpu_ms_per_step: int | None = None
    heap_bytes: int | None = None
    max_messages_per_vv: int | None = None
    max_message_bytes: int | None = None
    service_class: ServiceClassSpec | None = None
    # Its users besides its own login (named after its slug, an owner), each with a role.
    users: tuple[MemberSpec, ...] = ()


@dataclass(frozen=True)
class MemberSpec:
    """A user of a customer, with its role (one of MEMBER_ROLES) and optional e-mail address."""

    name: str
    role: str = DEFAULT_ROLE
    email: str | None = None


@dataclass(frozen=True)
class StaffSpec:
    """A staff user of the platform, in these staff groups (of STAFF_GROUPS; none: only what
    the admin gives them), with an optional e-mail address."""

    name: str
    groups: tuple[str, ...] = ()
    email: str | None = None


@dataclass(frozen=True)
class VVSpec:
    """A VV to submit: its program text, and the resolved file it came from (None if inline)."""

    customer: str
    name: str
    source: str
    program_path: Path | None
    submit_at_s: float = 0.0
    copies: int = 1


@dataclass(frozen=True)
class SensorSpecEntry:
    """An SDC entry the scenario adds; `kind` is one of SENSOR_KINDS, `params` is read-only."""

    name: str
    kind: str
    unit: str
    params: Mapping[str, Any] = field(hash=False)
    privileged: bool = False
    description: str | None = None
    kinds: tuple[str, ...] = ()  # the vehicle kinds that can carry it (empty: every kind)


@dataclass(frozen=True)
class FleetEvent:
    """A change to the fleet at simulated time `at_s`.

    `action` is one of VEHICLE_ACTIONS, acting on `vehicle`, or ADD_ACTION, adding
    `add_vehicle` (then `vehicle` is the added vehicle's name).
    """

    at_s: float
    action: str
    vehicle: str | None
    add_vehicle: VehicleSpec | None


@dataclass(frozen=True)
class Scenario:
    """A whole validated scenario; `events` are sorted by `at_s` (stable)."""

    name: str
    ground_stations: tuple[GroundStationSpec, ...]
    vehicles: tuple[VehicleSpec, ...]
    customers: tuple[CustomerSpec, ...]
    vvs: tuple[VVSpec, ...]
    sensors: tuple[SensorSpecEntry, ...]
    events: tuple[FleetEvent, ...]
    path: Path | None
    description: str | None = None
    no_fly_zones: tuple[NoFlyZoneSpec, ...] = ()
    staff: tuple[StaffSpec, ...] = ()
    # (place in the file, user name) of each vehicle pilot that `staff` does not name: the
    # loader looks for them among the database's staff.
    outside_pilots: tuple[tuple[str, str], ...] = ()


# --- public functions --------------------------------------------------------------------------


def load_scenario(path: str | Path) -> Scenario:
    """Read and validate a scenario file.

    Input: the path of a UTF-8 JSON file; `program` paths inside it are relative to its
    directory. Output: the `Scenario`, with `path` set to the file's resolved path.
    Errors: `ScenarioError` (with `file` set) when the file cannot be read, is not valid JSON
    (the message and the `line`/`column` attributes say where), or breaks the contract.
    """
    file_path = Path(path)
    file = str(path)
    try:
        text = file_path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ScenarioError("", f"no such file: {file_path.resolve()}", file=file) from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ScenarioError("", f"cannot read the scenario: {exc}", file=file) from exc
    try:
        data = json.loads(text, object_pairs_hook=_JsonObject.from_pairs)
    except json.JSONDecodeError as exc:
        raise ScenarioError(
            "",
            f"invalid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}",
            file=file,
            line=exc.lineno,
            column=exc.colno,
        ) from None
    resolved = file_path.resolve()
    scenario = parse_scenario(data, base_dir=resolved.parent, file=file)
    return replace(scenario, path=resolved)


def parse_scenario(data: Any, *, base_dir: Path, file: str | None = None) -> Scenario:
    """Validate decoded scenario JSON and build a `Scenario`.

    Inputs: `data` as `json.loads` gives it; `base_dir`, the directory that `program` paths
    are relative to (program files are read here, as UTF-8); `file`, a name for messages.
    Output: the `Scenario` (`path` is None; `load_scenario` sets it). A missing `name` becomes
    the file's stem, or "scenario". Events are sorted by `at_s`, keeping file order for ties.
    Errors: `ScenarioError` for the first problem found, with its path and message.
    """
    try:
        return _Parser(base_dir, default_name=_default_scenario_name(file)).scenario(data)
    except ScenarioError as exc:
        raise exc.in_file(file) from None


def _default_scenario_name(file: str | None) -> str:
    """The name a scenario without `name` gets: the file's stem, or "scenario"."""
    return Path(file).stem if file else "scenario"


def vv_instances(scenario: Scenario) -> list[tuple[VVSpec, str]]:
    """Expand `copies`: one (spec, instance name) per VV to submit, in file order.

    A spec with copies=1 keeps its name; copies=3 gives "NAME #1", "NAME #2", "NAME #3".
    Instance names are unique per customer (`parse_scenario` checks it).
    """
    return [(spec, name) for spec in scenario.vvs for name in _instance_names(spec)]


# --- internals ---------------------------------------------------------------------------------


class _JsonObject(dict[str, Any]):
    """A decoded JSON object that remembers keys the text gave more than once."""

    duplicates: tuple[str, ...] = ()

    @classmethod
    def from_pairs(cls, pairs: list[tuple[str, Any]]) -> _JsonObject:
        obj = cls(pairs)
        seen: set[str] = set()
        dups: list[str] = []
        for key, _ in pairs:
            if key in seen and key not in dups:
                dups.append(key)
            seen.add(key)
        obj.duplicates = tuple(dups)
        return obj


_TOP_REQUIRED = ("ground_stations", "vehicles", "customers", "vvs")
_TOP_OPTIONAL = ("name", "description", "sensors", "events", "no_fly_zones", "staff")
_ZONE_REQUIRED = ("name", "area")
_ZONE_OPTIONAL = ("min_altitude_m", "max_altitude_m")
_GS_REQUIRED = ("name", "position")
# The altitudes are required of an aerial vehicle, and min_altitude_m of an underwater one
# (`_Parser.altitudes`); a ground or surface vehicle stays at 0 m.
_VEHICLE_REQUIRED = ("name", "depot", "area", "max_speed_mps", "sensors")
_VEHICLE_OPTIONAL = (
    "driver",
    "battery_s",
    "climb_rate_mps",
    "driver_url",
    "min_altitude_m",
    "max_altitude_m",
    "kind",
    "dive_rate_mps",
    "turn_rate_dps",
    "start",
    "pilots",
)
_CUSTOMER_REQUIRED = ("name", "max_parallel_vvs")
_CUSTOMER_QUOTAS = (
    "max_queued_vvs",
    "max_tasks_per_vv",
    "storage_bytes",
    "cpu_ms_per_step",
    "heap_bytes",
    "max_messages_per_vv",
    "max_message_bytes",
)
# The least value of a quota where it is not 1 (as accounts.models.Customer validates them): a
# customer's VVs may be allowed to send no message at all; a message may be kept to 2 bytes.
_QUOTA_MINIMUM = {"max_messages_per_vv": 0, "max_message_bytes": 2}
_CUSTOMER_OPTIONAL = ("privileged", "service_class", "users", *_CUSTOMER_QUOTAS)
_MEMBER_REQUIRED = ("name",)
_MEMBER_OPTIONAL = ("role", "email")
_STAFF_REQUIRED = ("name",)
_STAFF_OPTIONAL = ("groups", "email")
# What Django's user names allow (UnicodeUsernameValidator, at most 150 characters).
_USER_NAME = re.compile(r"[\w.@+-]+\Z")
_USER_NAME_MAX = 150
_SERVICE_CLASS_REQUIRED = ("name", "p95_s")
_SERVICE_CLASS_OPTIONAL = ("weight",)
_VV_REQUIRED = ("customer", "name")
_VV_OPTIONAL = ("program", "source", "submit_at_s", "copies")
_SENSOR_REQUIRED = ("name", "kind", "unit")
_ALTITUDES_REQUIRED = {
    AERIAL: ("min_altitude_m", "max_altitude_m"),
    UNDERWATER: ("min_altitude_m",),
}
_SENSOR_OPTIONAL = ("params", "privileged", "description", "kinds")
_EVENT_REQUIRED = ("at_s",)
_EVENT_OPTIONAL = ("vehicle", "action", "add_vehicle")


def _json_type(value: Any) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, int | float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list | tuple):
        return "an array"
    if isinstance(value, Mapping):
        return "an object"
    return type(value).__name__


def _join(path: str, key: str) -> str:
    return f"{path}.{key}" if path else key


def _instance_names(spec: VVSpec) -> list[str]:
    if spec.copies == 1:
        return [spec.name]
    return [f"{spec.name} #{k}" for k in range(1, spec.copies + 1)]


def _object(
    value: Any, path: str, required: Sequence[str], optional: Sequence[str]
) -> Mapping[str, Any]:
    """`value` as an object whose keys are all allowed and whose required keys are there."""
    if not isinstance(value, Mapping):
        raise ScenarioError(path, f"must be an object, got {_json_type(value)}")
    duplicates: tuple[str, ...] = getattr(value, "duplicates", ())
    if duplicates:
        raise ScenarioError(path, f"key {duplicates[0]!r} is given more than once")
    allowed = set(required) | set(optional)
    for key in value:
        if key not in allowed:
            raise ScenarioError(
                path, f"unknown key {key!r} (allowed: {', '.join(sorted(allowed))})"
            )
    for key in required:
        if key not in value:
            raise ScenarioError(path, f"missing required key {key!r}")
    return value


def _list(value: Any, path: str) -> list[Any]:
    if not isinstance(value, list):
        raise ScenarioError(path, f"must be an array, got {_json_type(value)}")
    return value


def _string(value: Any, path: str, *, allow_blank: bool = False) -> str:
    if not isinstance(value, str):
        raise ScenarioError(path, f"must be a string, got {_json_type(value)}")
    if not allow_blank and not value.strip():
        raise ScenarioError(path, "must not be empty")
    return value


def _bool(value: Any, path: str) -> bool:
    if not isinstance(value, bool):
        raise ScenarioError(path, f"must be true or false, got {_json_type(value)}")
    return value


def _number(value: Any, path: str) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise ScenarioError(path, f"must be a number, got {_json_type(value)}")
    number = float(value)
    if not math.isfinite(number):
        raise ScenarioError(path, f"must be a finite number, got {value!r}")
    return number


def _positive(value: Any, path: str) -> float:
    number = _number(value, path)
    if number <= 0:
        raise ScenarioError(path, f"must be greater than 0, got {value!r}")
    return number


def _non_negative(value: Any, path: str) -> float:
    number = _number(value, path)
    if number < 0:
        raise ScenarioError(path, f"must not be negative, got {value!r}")
    return number


def _integer(value: Any, path: str, *, minimum: int) -> int:
    number = _number(value, path)
    if not number.is_integer():
        raise ScenarioError(path, f"must be a whole number, got {value!r}")
    if number < minimum:
        raise ScenarioError(path, f"must be at least {minimum}, got {value!r}")
    return int(value)


def _vehicle_kind(value: Any, path: str) -> str:
    kind = _string(value, path)
    if kind not in KINDS:
        raise ScenarioError(path, f"unknown vehicle kind {kind!r} (one of: {', '.join(KINDS)})")
    return kind


def _user_name(value: Any, path: str) -> str:
    name = _string(value, path)
    if len(name) > _USER_NAME_MAX or not _USER_NAME.match(name):
        raise ScenarioError(
            path,
            f"{name!r} is not a user name: letters, digits and @ . + - _ only, "
            f"at most {_USER_NAME_MAX} characters",
        )
    return name


def _staff_group(value: Any, path: str) -> str:
    group = _string(value, path)
    if group not in STAFF_GROUPS:
        raise ScenarioError(
            path, f"unknown staff group {group!r} (one of: {', '.join(STAFF_GROUPS)})"
        )
    return group


def _distinct(value: Any, path: str, read: Callable[[Any, str], str]) -> tuple[str, ...]:
    """A list of strings, each checked by `read`, none given twice."""
    first_at: dict[str, str] = {}
    for i, item in enumerate(_list(value, path)):
        item_path = f"{path}[{i}]"
        name = read(item, item_path)
        if name in first_at:
            raise ScenarioError(item_path, f"{name!r} is given twice (also at {first_at[name]})")
        first_at[name] = item_path
    return tuple(first_at)


def _position(value: Any, path: str) -> Position:
    items = _list(value, path)
    if len(items) != 3:
        raise ScenarioError(path, f"must be [lat, lng, alt], got {len(items)} values")
    lat, lng, alt = (_number(item, f"{path}[{i}]") for i, item in enumerate(items))
    try:
        return Position(lat, lng, alt)
    except ValueError as exc:
        raise ScenarioError(path, str(exc)) from None


def _area(value: Any, path: str) -> tuple[tuple[float, float], ...]:
    items = _list(value, path)
    ring: list[tuple[float, float]] = []
    for i, item in enumerate(items):
        point_path = f"{path}[{i}]"
        pair = _list(item, point_path)
        if len(pair) != 2:
            raise ScenarioError(point_path, f"must be [lat, lng], got {len(pair)} values")
        lat, lng = (_number(x, f"{point_path}[{k}]") for k, x in enumerate(pair))
        try:
            Position(lat, lng)
        except ValueError as exc:
            raise ScenarioError(point_path, str(exc)) from None
        ring.append((lat, lng))
    if len(set(ring)) < 3:
        raise ScenarioError(
            path, f"a polygon needs at least 3 distinct points, got {len(set(ring))}"
        )
    if ring[0] != ring[-1]:
        raise ScenarioError(
            path,
            f"the polygon is not closed: the first point {list(ring[0])} "
            f"differs from the last {list(ring[-1])} (repeat the first point at the end)",
        )
    # Validity does not depend on the axis order, and keeping (lat, lng) makes the
    # coordinates that explain_validity reports read like the file.
    polygon = Polygon(ring)
    if not polygon.is_valid:
        raise ScenarioError(path, f"invalid polygon: {explain_validity(polygon)}")
    return tuple(ring)


def _check_unique(names: Iterable[tuple[str, str]], what: str) -> None:
    """Raise at the second of two equal names; `names` yields (name, path of the name)."""
    first_at: dict[str, str] = {}
    for name, path in names:
        if name in first_at:
            raise ScenarioError(path, f"duplicate {what} name {name!r} (also at {first_at[name]})")
        first_at[name] = path


def _check_service_classes(customers: Sequence[CustomerSpec]) -> None:
    """Customers that name the same service class must give it the same target and weight:
    raise at the second that differs, naming both customers."""
    first: dict[str, int] = {}
    for i, customer in enumerate(customers):
        spec = customer.service_class
        if spec is None:
            continue
        k = first.setdefault(spec.name, i)
        seen = customers[k].service_class
        if seen is not None and seen != spec:
            raise ScenarioError(
                f"customers[{i}].service_class",
                f"service class {spec.name!r} is p95_s {spec.p95_s:g}, weight {spec.weight:g} "
                f"for customer {customer.name!r} but p95_s {seen.p95_s:g}, weight "
                f"{seen.weight:g} for customer {customers[k].name!r} (customers[{k}]): "
                "a class has one target and one weight",
            )


class _Parser:
    """One validation pass over a scenario document; raises at the first problem."""

    def __init__(self, base_dir: Path, *, default_name: str) -> None:
        self.base_dir = base_dir
        self.default_name = default_name
        # Every vehicle parsed (also those events add) with its place in the file: for the
        # check of their pilots once the staff are known.
        self.vehicle_places: list[tuple[str, VehicleSpec]] = []

    def scenario(self, data: Any) -> Scenario:
        doc = _object(data, "", _TOP_REQUIRED, _TOP_OPTIONAL)
        name = _string(doc["name"], "name") if "name" in doc else self.default_name
        description = (
            _string(doc["description"], "description", allow_blank=True)
            if "description" in doc
            else None
        )
        ground_stations = tuple(
            self.ground_station(item, f"ground_stations[{i}]")
            for i, item in enumerate(_list(doc["ground_stations"], "ground_stations"))
        )
        _check_unique(
            ((gs.name, f"ground_stations[{i}].name") for i, gs in enumerate(ground_stations)),
            "ground station",
        )
        vehicles = tuple(
            self.vehicle(item, f"vehicles[{i}]")
            for i, item in enumerate(_list(doc["vehicles"], "vehicles"))
        )
        _check_unique(((v.name, f"vehicles[{i}].name") for i, v in enumerate(vehicles)), "vehicle")
        customers = tuple(
            self.customer(item, f"customers[{i}]")
            for i, item in enumerate(_list(doc["customers"], "customers"))
        )
        _check_unique(
            ((c.name, f"customers[{i}].name") for i, c in enumerate(customers)), "customer"
        )
        _check_service_classes(customers)
        staff = tuple(
            self.staff_user(item, f"staff[{i}]")
            for i, item in enumerate(_list(doc.get("staff", []), "staff"))
        )
        # User names are the platform's, not a customer's: one name, one user.
        _check_unique(
            [
                *(
                    (user.name, f"customers[{i}].users[{k}].name")
                    for i, customer in enumerate(customers)
                    for k, user in enumerate(customer.users)
                ),
                *((user.name, f"staff[{i}].name") for i, user in enumerate(staff)),
            ],
            "user",
        )
        sensors = tuple(
            self.sensor(item, f"sensors[{i}]")
            for i, item in enumerate(_list(doc.get("sensors", []), "sensors"))
        )
        _check_unique(((s.name, f"sensors[{i}].name") for i, s in enumerate(sensors)), "sensor")
        vvs = self.vvs(_list(doc["vvs"], "vvs"), {c.name for c in customers})
        if vvs and not ground_stations:
            raise ScenarioError(
                "ground_stations", "at least one ground station is required when there are VVs"
            )
        events = self.events(_list(doc.get("events", []), "events"), vehicles)
        zones = tuple(
            self.no_fly_zone(item, f"no_fly_zones[{i}]")
            for i, item in enumerate(_list(doc.get("no_fly_zones", []), "no_fly_zones"))
        )
        _check_unique(
            ((z.name, f"no_fly_zones[{i}].name") for i, z in enumerate(zones)), "no-fly zone"
        )
        outside_pilots = self.check_pilots(customers, staff)
        return Scenario(
            name=name,
            ground_stations=ground_stations,
            vehicles=vehicles,
            customers=customers,
            vvs=vvs,
            sensors=sensors,
            events=events,
            path=None,
            description=description,
            no_fly_zones=zones,
            staff=staff,
            outside_pilots=outside_pilots,
        )

    def check_pilots(
        self, customers: Sequence[CustomerSpec], staff: Sequence[StaffSpec]
    ) -> tuple[tuple[str, str], ...]:
        """A vehicle's pilots are staff: a customer's user of the scenario is refused. Returns
        (place, user name) of each pilot the scenario's `staff` does not name, for the loader
        to find among the database's staff."""
        members = {
            user.name: f"customers[{i}].users[{k}]"
            for i, customer in enumerate(customers)
            for k, user in enumerate(customer.users)
        }
        staff_names = {user.name for user in staff}
        outside: list[tuple[str, str]] = []
        for path, spec in self.vehicle_places:
            for k, pilot in enumerate(spec.pilots or ()):
                place = f"{path}.pilots[{k}]"
                if pilot in members:
                    raise ScenarioError(
                        place,
                        f"{pilot!r} is a customer's user ({members[pilot]}); a pilot is staff "
                        "(list them in staff, with the group 'pilot')",
                    )
                if pilot not in staff_names:
                    outside.append((place, pilot))
        return tuple(outside)

    def ground_station(self, value: Any, path: str) -> GroundStationSpec:
        obj = _object(value, path, _GS_REQUIRED, ())
        return GroundStationSpec(
            name=_string(obj["name"], _join(path, "name")),
            position=_position(obj["position"], _join(path, "position")),
        )

    def vehicle(self, value: Any, path: str) -> VehicleSpec:
        obj = _object(value, path, _VEHICLE_REQUIRED, _VEHICLE_OPTIONAL)
        name = _string(obj["name"], _join(path, "name"))
        kind = _vehicle_kind(obj.get("kind", DEFAULT_KIND), _join(path, "kind"))
        depot = _position(obj["depot"], _join(path, "depot"))
        area = _area(obj["area"], _join(path, "area"))
        min_alt, max_alt = self.altitudes(obj, path, kind)
        max_speed = _positive(obj["max_speed_mps"], _join(path, "max_speed_mps"))
        problems = limit_problems(
            kind,
            min_altitude_m=min_alt,
            max_altitude_m=max_alt,
            max_speed_mps=max_speed,
            depot_alt_m=depot.alt,
        )
        for key, problem in problems.items():  # the first one, like every other check
            if key == "depot_alt":
                raise ScenarioError(_join(path, "depot.alt"), f"{problem}, got {depot.alt:g}")
            raise ScenarioError(_join(path, key), f"{problem}, got {obj.get(key, 0)!r}")
        dive_rate = self.kind_rate(obj, path, "dive_rate_mps", kind, (UNDERWATER,))
        turn_rate = self.kind_rate(obj, path, "turn_rate_dps", kind, (GROUND, SURFACE))
        sensors_path = _join(path, "sensors")
        sensors = tuple(
            _string(item, f"{sensors_path}[{i}]")
            for i, item in enumerate(_list(obj["sensors"], sensors_path))
        )
        if not sensors:
            raise ScenarioError(sensors_path, "a vehicle needs at least one sensor")
        driver = _string(obj.get("driver", "sim"), _join(path, "driver"))
        if driver not in DRIVERS:
            raise ScenarioError(
                _join(path, "driver"),
                f"unknown driver {driver!r} (one of: {', '.join(DRIVERS)})",
            )
        battery_s = (
            _positive(obj["battery_s"], _join(path, "battery_s")) if "battery_s" in obj else None
        )
        climb_rate = (
            _positive(obj["climb_rate_mps"], _join(path, "climb_rate_mps"))
            if "climb_rate_mps" in obj
            else None
        )
        driver_url = (
            _string(obj["driver_url"], _join(path, "driver_url")) if "driver_url" in obj else None
        )
        start = None
        if "start" in obj:
            start = _position(obj["start"], _join(path, "start"))
            if kind != AERIAL or driver != "sim":
                raise ScenarioError(
                    _join(path, "start"), "only a simulated aerial vehicle starts in the air"
                )
            if start.alt <= depot.alt:
                raise ScenarioError(
                    _join(path, "start"),
                    f"a vehicle starts in the air, above its depot's {depot.alt:g} m, "
                    f"got {start.alt:g} m (leave start out for one landed at its depot)",
                )
        pilots = (
            _distinct(obj["pilots"], _join(path, "pilots"), _user_name) if "pilots" in obj else None
        )
        spec = VehicleSpec(
            name=name,
            depot=depot,
            area=area,
            min_altitude_m=min_alt,
            max_altitude_m=max_alt,
            max_speed_mps=max_speed,
            sensors=sensors,
            driver=driver,
            battery_s=battery_s,
            climb_rate_mps=climb_rate,
            driver_url=driver_url,
            kind=kind,
            dive_rate_mps=dive_rate,
            turn_rate_dps=turn_rate,
            start=start,
            pilots=pilots,
        )
        self.vehicle_places.append((path, spec))
        return spec

    def altitudes(self, obj: Mapping[str, Any], path: str, kind: str) -> tuple[float, float]:
        """A vehicle's (min_altitude_m, max_altitude_m): both required of an aerial vehicle;
        a ground or surface vehicle's default to 0; an underwater vehicle needs how deep it
        goes (min_altitude_m below 0), its max_altitude_m defaults to 0 (the surface)."""
        for key in _ALTITUDES_REQUIRED.get(kind, ()):
            if key not in obj:
                what = f"missing required key {key!r}"
                if kind == UNDERWATER:
                    what += " (how deep it goes: below 0 is depth)"
                raise ScenarioError(path, what)
        # Only an underwater vehicle goes below 0 m; the others keep today's message.
        read = _number if kind == UNDERWATER else _non_negative
        min_alt = read(obj.get("min_altitude_m", 0.0), _join(path, "min_altitude_m"))
        max_alt = read(obj.get("max_altitude_m", 0.0), _join(path, "max_altitude_m"))
        if min_alt > max_alt:
            raise ScenarioError(
                _join(path, "min_altitude_m"),
                f"min_altitude_m ({obj['min_altitude_m']!r}) is above "
                f"max_altitude_m ({obj.get('max_altitude_m', 0)!r})",
            )
        if kind == UNDERWATER and min_alt >= 0:
            raise ScenarioError(
                _join(path, "min_altitude_m"),
                "an underwater vehicle dives: min_altitude_m is how deep it goes and must be "
                f"below 0 (e.g. -50), got {obj['min_altitude_m']!r}",
            )
        return min_alt, max_alt

    def kind_rate(
        self, obj: Mapping[str, Any], path: str, key: str, kind: str, kinds: tuple[str, ...]
    ) -> float | None:
        """A rate only some kinds have (a dive rate, a turn rate), or None when not given."""
        if key not in obj:
            return None
        if kind not in kinds:
            raise ScenarioError(
                _join(path, key),
                f"only {' and '.join(kinds)} vehicles have a {key}; this one is {kind}",
            )
        return _positive(obj[key], _join(path, key))

    def no_fly_zone(self, value: Any, path: str) -> NoFlyZoneSpec:
        obj = _object(value, path, _ZONE_REQUIRED, _ZONE_OPTIONAL)
        low = _non_negative(obj.get("min_altitude_m", 0.0), _join(path, "min_altitude_m"))
        high = None
        if obj.get("max_altitude_m") is not None:
            high = _non_negative(obj["max_altitude_m"], _join(path, "max_altitude_m"))
            if high < low:
                raise ScenarioError(
                    _join(path, "max_altitude_m"),
                    f"max_altitude_m ({high:g}) is below min_altitude_m ({low:g})",
                )
        return NoFlyZoneSpec(
            name=_string(obj["name"], _join(path, "name")),
            area=_area(obj["area"], _join(path, "area")),
            min_altitude_m=low,
            max_altitude_m=high,
        )

    def customer(self, value: Any, path: str) -> CustomerSpec:
        obj = _object(value, path, _CUSTOMER_REQUIRED, _CUSTOMER_OPTIONAL)
        quotas = {
            key: _integer(obj[key], _join(path, key), minimum=_QUOTA_MINIMUM.get(key, 1))
            for key in _CUSTOMER_QUOTAS
            if key in obj
        }
        return CustomerSpec(
            name=_string(obj["name"], _join(path, "name")),
            max_parallel_vvs=_integer(
                obj["max_parallel_vvs"], _join(path, "max_parallel_vvs"), minimum=1
            ),
            privileged=_bool(obj.get("privileged", False), _join(path, "privileged")),
            service_class=(
                self.service_class(obj["service_class"], _join(path, "service_class"))
                if "service_class" in obj
                else None
            ),
            users=tuple(
                self.member(item, f"{_join(path, 'users')}[{k}]")
                for k, item in enumerate(_list(obj.get("users", []), _join(path, "users")))
            ),
            **quotas,
        )

    def member(self, value: Any, path: str) -> MemberSpec:
        obj = _object(value, path, _MEMBER_REQUIRED, _MEMBER_OPTIONAL)
        name = _user_name(obj["name"], _join(path, "name"))
        role = _string(obj.get("role", DEFAULT_ROLE), _join(path, "role"))
        if role not in MEMBER_ROLES:
            raise ScenarioError(
                _join(path, "role"), f"unknown role {role!r} (one of: {', '.join(MEMBER_ROLES)})"
            )
        return MemberSpec(name=name, role=role, email=self.email(obj, path))

    def staff_user(self, value: Any, path: str) -> StaffSpec:
        obj = _object(value, path, _STAFF_REQUIRED, _STAFF_OPTIONAL)
        return StaffSpec(
            name=_user_name(obj["name"], _join(path, "name")),
            groups=_distinct(obj.get("groups", []), _join(path, "groups"), _staff_group),
            email=self.email(obj, path),
        )

    def email(self, obj: Mapping[str, Any], path: str) -> str | None:
        """A user's e-mail address, or None; the loader checks it as Django does."""
        if "email" not in obj:
            return None
        email = _string(obj["email"], _join(path, "email")).strip()
        if "@" not in email:
            raise ScenarioError(_join(path, "email"), f"{email!r} is not an e-mail address")
        return email

    def service_class(self, value: Any, path: str) -> ServiceClassSpec:
        obj = _object(value, path, _SERVICE_CLASS_REQUIRED, _SERVICE_CLASS_OPTIONAL)
        name = _string(obj["name"], _join(path, "name"))
        if len(name) > 60:
            raise ScenarioError(_join(path, "name"), f"at most 60 characters, got {len(name)}")
        return ServiceClassSpec(
            name=name,
            p95_s=_positive(obj["p95_s"], _join(path, "p95_s")),
            weight=_positive(obj.get("weight", 1.0), _join(path, "weight")),
        )

    def sensor(self, value: Any, path: str) -> SensorSpecEntry:
        obj = _object(value, path, _SENSOR_REQUIRED, _SENSOR_OPTIONAL)
        kind = _string(obj["kind"], _join(path, "kind"))
        if kind not in SENSOR_KINDS:
            raise ScenarioError(
                _join(path, "kind"),
                f"unknown sensor kind {kind!r} (one of: {', '.join(SENSOR_KINDS)})",
            )
        params = obj.get("params", {})
        if not isinstance(params, Mapping):
            raise ScenarioError(
                _join(path, "params"), f"must be an object, got {_json_type(params)}"
            )
        description = (
            _string(obj["description"], _join(path, "description"), allow_blank=True)
            if "description" in obj
            else None
        )
        return SensorSpecEntry(
            name=_string(obj["name"], _join(path, "name")),
            kind=kind,
            unit=_string(obj["unit"], _join(path, "unit"), allow_blank=True),
            # Round-tripping through JSON copies the params deeply and keeps them plain JSON.
            params=MappingProxyType(json.loads(json.dumps(params))),
            privileged=_bool(obj.get("privileged", False), _join(path, "privileged")),
            description=description,
            kinds=self.sensor_kinds(obj.get("kinds", []), _join(path, "kinds")),
        )

    def sensor_kinds(self, value: Any, path: str) -> tuple[str, ...]:
        """The vehicle kinds that can carry an SDC entry (an empty list: every kind)."""
        return tuple(
            _vehicle_kind(item, f"{path}[{i}]") for i, item in enumerate(_list(value, path))
        )

    def vvs(self, items: list[Any], customers: set[str]) -> tuple[VVSpec, ...]:
        specs: list[VVSpec] = []
        # Instance names (after expanding copies) must be unique per customer, so that
        # "X" with copies 2 and a separate "X #1" are refused too.
        first_at: dict[tuple[str, str], str] = {}
        for i, item in enumerate(items):
            path = f"vvs[{i}]"
            spec = self.vv(item, path)
            if spec.customer not in customers:
                raise ScenarioError(
                    _join(path, "customer"),
                    f"unknown customer {spec.customer!r} (not in customers)",
                )
            for instance in _instance_names(spec):
                key = (spec.customer, instance)
                if key in first_at:
                    raise ScenarioError(
                        _join(path, "name"),
                        f"duplicate VV name {instance!r} for customer {spec.customer!r} "
                        f"(also at {first_at[key]})",
                    )
                first_at[key] = _join(path, "name")
            specs.append(spec)
        return tuple(specs)

    def vv(self, value: Any, path: str) -> VVSpec:
        obj = _object(value, path, _VV_REQUIRED, _VV_OPTIONAL)
        customer = _string(obj["customer"], _join(path, "customer"))
        name = _string(obj["name"], _join(path, "name"))
        if ("program" in obj) == ("source" in obj):
            raise ScenarioError(
                path, "give exactly one of 'program' (a file) and 'source' (inline JavaScript)"
            )
        program_path: Path | None
        if "program" in obj:
            program_path, source = self.program(obj["program"], _join(path, "program"))
        else:
            program_path = None
            source = _string(obj["source"], _join(path, "source"), allow_blank=True)
        return VVSpec(
            customer=customer,
            name=name,
            source=source,
            program_path=program_path,
            submit_at_s=_non_negative(obj.get("submit_at_s", 0.0), _join(path, "submit_at_s")),
            copies=_integer(obj.get("copies", 1), _join(path, "copies"), minimum=1),
        )

    def program(self, value: Any, path: str) -> tuple[Path, str]:
        relative = _string(value, path)
        resolved = (self.base_dir / relative).resolve()
        if not resolved.is_file():
            raise ScenarioError(path, f"program file not found: {resolved}")
        try:
            return resolved, resolved.read_text(encoding="utf-8")
        except (OSError, UnicodeDecodeError) as exc:
            raise ScenarioError(path, f"cannot read program file {resolved}: {exc}") from exc

    def events(self, items: list[Any], vehicles: tuple[VehicleSpec, ...]) -> tuple[FleetEvent, ...]:
        parsed = [
            (self.event(item, f"events[{i}]"), f"events[{i}]") for i, item in enumerate(items)
        ]
        # sorted() is stable: events at the same time keep their file order.
        parsed.sort(key=lambda pair: pair[0].at_s)
        # Top-level names are unique already (checked by the caller).
        names: dict[str, str] = {v.name: f"vehicles[{i}].name" for i, v in enumerate(vehicles)}
        removed: dict[str, float] = {}
        for event, path in parsed:
            if event.add_vehicle is not None:
                added = event.add_vehicle.name
                name_path = _join(path, "add_vehicle.name")
                if added in names:
                    raise ScenarioError(
                        name_path, f"duplicate vehicle name {added!r} (also at {names[added]})"
                    )
                names[added] = name_path
                continue
            assert event.vehicle is not None
            if event.vehicle not in names:
                raise ScenarioError(
                    _join(path, "vehicle"),
                    f"unknown vehicle {event.vehicle!r} (not in vehicles, "
                    "nor added by an earlier event)",
                )
            if event.vehicle in removed:
                raise ScenarioError(
                    _join(path, "vehicle"),
                    f"vehicle {event.vehicle!r} was already removed at "
                    f"{removed[event.vehicle]:g} s",
                )
            if event.action == "remove":
                removed[event.vehicle] = event.at_s
        return tuple(event for event, _ in parsed)

    def event(self, value: Any, path: str) -> FleetEvent:
        obj = _object(value, path, _EVENT_REQUIRED, _EVENT_OPTIONAL)
        at_s = _non_negative(obj["at_s"], _join(path, "at_s"))
        if "add_vehicle" in obj:
            if "vehicle" in obj:
                raise ScenarioError(
                    path, "an event has either 'add_vehicle' or 'vehicle' and 'action', not both"
                )
            if "action" in obj and obj["action"] != ADD_ACTION:
                raise ScenarioError(
                    _join(path, "action"),
                    f"an 'add_vehicle' event takes no action other than {ADD_ACTION!r}, "
                    f"got {obj['action']!r}",
                )
            spec = self.vehicle(obj["add_vehicle"], _join(path, "add_vehicle"))
            return FleetEvent(at_s=at_s, action=ADD_ACTION, vehicle=spec.name, add_vehicle=spec)
        for key in ("vehicle", "action"):
            if key not in obj:
                raise ScenarioError(
                    path, f"missing required key {key!r} (or give 'add_vehicle' instead)"
                )
        vehicle = _string(obj["vehicle"], _join(path, "vehicle"))
        action = _string(obj["action"], _join(path, "action"))
        if action not in VEHICLE_ACTIONS:
            raise ScenarioError(
                _join(path, "action"),
                f"unknown action {action!r} (one of: {', '.join(VEHICLE_ACTIONS)})",
            )
        return FleetEvent(at_s=at_s, action=action, vehicle=vehicle, add_vehicle=None)
