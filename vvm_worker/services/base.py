"""What every VVM service shares: the VVM (clock, dispatcher, sensor world, runtime) and the
small helpers about hosts and pending requests."""

from __future__ import annotations

import datetime as dt
import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from dataclasses import field as dataclass_field
from typing import Any, Protocol

from django.core.exceptions import ValidationError
from django.db import transaction
from django.db.models import Count, OuterRef, Subquery
from django.db.models.functions import Coalesce

from fleet.geo import Position, distance_m
from fleet.models import GroundStation, SensorType
from fleet.selectors import UnknownSensors, sensors_by_name
from fleet.simulation import SensorField
from missions.models import (
    ACTIVE_STATUSES,
    VirtualVehicle,
)
from vvm_worker.clock import Clock
from vvm_worker.delivery import Notifier, Unheard
from vvm_worker.dispatch import Announcer, Dispatcher, Silent
from vvm_worker.runtime import (
    PendingRequest,
    Runtime,
    SyntaxProblem,
)
from vvm_worker.services.store import ground_stations

logger = logging.getLogger("cpcc.vvm")


@dataclass(frozen=True)
class LocalRV:
    """What the process that hosts an RV knows of it now, as its row would say once written:
    its status (None: its row's, which another process may have changed a moment ago), its
    last reported position, its open tasks in the order its planner last meant to serve
    them, and the service classes of its open tasks (oldest first; None: no class), which
    the mapper's reserve counts."""

    status: str | None
    position: Position
    route: tuple[Position, ...]
    classes: tuple[int | None, ...] = ()


@dataclass(frozen=True)
class Settled:
    """An RV whose host settled it: where it last said it is (None: where its row says)."""

    position: Position | None


class LocalFleet(Protocol):
    """The RVs whose control loops run in this process, which the services ask and tell
    directly instead of through the database and the dispatcher."""

    def live(self, vehicle_id: int, *, route: bool = True) -> LocalRV | None:
        """The RV as it is now, if this process hosts it and its loop has reported (else None:
        read its row). ``route``: False when the caller does not need its open tasks (the
        route is then empty)."""
        ...

    def settle(self, vehicle_id: int, *, tasks_done: int = 0) -> Settled | None:
        """Write what the RV reported and is still to be on the track of the VVs aboard it,
        in the caller's transaction, which is about to change who is aboard; count
        ``tasks_done`` more tasks served. None when this process does not settle this RV
        (then the caller counts ``tasks_done`` itself)."""
        ...

    def assigned(self, vehicle_id: int, tasks: Sequence[Any]) -> bool:
        """These tasks (saved by the end of the caller's transaction) were put on the RV's
        list: True when this process hosts it and its loop was told (no vehicle_changed)."""
        ...


@dataclass
class VVM:
    """What the services need from the process they run in: the clock, who to tell what to
    do next, the sensor world, and the VV runtime with its warm contexts."""

    clock: Clock
    dispatcher: Dispatcher
    field: SensorField
    world_seed: int = 0
    runtime: Runtime = dataclass_field(default_factory=Runtime)
    # Distributed platform: an RV whose worker has not reported for this long takes no work.
    # None in `simulate`, where every RV's loop runs in the same process.
    lease_s: float | None = None
    # Who hears of changes as they happen (the live map's feed).
    announcer: Announcer = dataclass_field(default_factory=Silent)
    # Every host runs in this process with this one runtime (`simulate`): a VV that migrates
    # keeps its warm context, which the next host would otherwise rebuild by replay.
    hosts_share_runtime: bool = False
    # The RVs whose hosts run in this process with this runtime (an rvworker of several RVs):
    # a VV that migrates between two of them keeps its warm context too.
    local_rvs: set[int] = dataclass_field(default_factory=set)
    # Those RVs' loops, as the services see them (None: ask the database, tell the dispatcher).
    local_fleet: LocalFleet | None = None
    # Inside a unit of work that read them ahead (``rv_statuses_read_ahead``): the statuses
    # of the local RVs, as that read gives them.
    statuses_ahead: Callable[[], dict[int, str]] | None = None
    # Who tells the customers' webhooks and e-mail recipients that a VV ended or a task was
    # done (vvm_worker/services/notifications.py); nobody in `simulate` and in most tests.
    notifier: Notifier = dataclass_field(default_factory=Unheard)
    # The service classes that gave way when routing last looked, and when (platform clock):
    # see ``service_levels.classes_giving_way``.
    giving_way_seen: tuple[float, frozenset[int | None]] | None = None

    @property
    def listened(self) -> bool:
        """Whether anyone listens for changes (the map): nobody pays for events unheard."""
        return not isinstance(self.announcer, Silent)

    def announce(self, make: Callable[[], dict[str, Any] | Iterable[dict[str, Any]]]) -> None:
        """Tell the listeners of a change: ``make`` builds the event (or events), and is
        called only when someone listens."""
        if not self.listened:
            return
        events = make()
        for event in [events] if isinstance(events, dict) else events:
            self.announcer.announce(event)

    def announce_at_commit(
        self, make: Callable[[], dict[str, Any] | Iterable[dict[str, Any]]]
    ) -> None:
        """``announce``, with the event built once the transaction commits: for rows whose
        keys a deferred insert sets only by the end of the unit of work
        (``cpcc_site.prepared.deferred``)."""
        if self.listened:
            transaction.on_commit(lambda: self.announce(make))

    def settle_host(self, vehicle: Any) -> None:
        """Before a VV boards or leaves this RV (a Vehicle row read in this transaction):
        its reports that wait are written, and the row says where it is now."""
        if self.local_fleet is None or vehicle is None:
            return
        settled = self.local_fleet.settle(vehicle.pk)
        if settled is not None and settled.position is not None:
            here = settled.position
            vehicle.lat, vehicle.lng, vehicle.alt = here.lat, here.lng, here.alt

    def keeps_context(self, vehicle_id: int | None) -> bool:
        """Whether a VV moving to this RV (None: a ground station) keeps its warm context."""
        return self.hosts_share_runtime or (vehicle_id is not None and vehicle_id in self.local_rvs)


class VVAlreadyEnded(RuntimeError):
    """The VV had already ended: there is nothing to cancel, and no message reaches it."""

    def __init__(self, vv: VirtualVehicle) -> None:
        super().__init__(f"{vv.name} has already ended ({vv.status})")
        self.vv = vv


class ProgramRejected(ValueError):
    """A program that cannot be accepted (a syntax error), with where the problem is."""

    def __init__(self, problem: SyntaxProblem) -> None:
        super().__init__(str(problem))
        self.problem = problem


def ground_station_for(vv: VirtualVehicle, near: Position | None = None) -> GroundStation | None:
    """The ground station for a VV: the nearest to ``near`` (an RV it leaves), else the one
    with the fewest VVs; None when there is none."""
    if near is not None:
        stations = ground_stations()
        if not stations:
            return None
        return min(stations, key=lambda gs: (distance_m(near, gs.position), gs.name))
    loaded = ground_stations_loaded()
    if not loaded:
        return None
    return min(loaded, key=lambda gs: (gs.load, gs.name))


def ground_stations_loaded() -> list[GroundStation]:
    """Every ground station, each with ``load``: how many VVs that have not ended it holds."""
    on_it = (
        VirtualVehicle.objects.filter(host_gs=OuterRef("pk"), status__in=ACTIVE_STATUSES)
        .order_by()
        .values("host_gs")
        .annotate(n=Count("pk"))
        .values("n")
    )
    return list(GroundStation.objects.annotate(load=Coalesce(Subquery(on_it), 0)))


def pending_json(p: PendingRequest) -> dict[str, Any]:
    """A pending request as the VV row keeps it."""
    return p.to_json()


def pending_of(vv: VirtualVehicle) -> PendingRequest | None:
    return PendingRequest.from_json(vv.pending) if vv.pending else None


def customer_named(vv: VirtualVehicle) -> str:
    """The VV's customer as a log line names it: its slug when it was read with the VV (the
    step's read does), else its id; a log line costs no query."""
    if VirtualVehicle.customer.is_cached(vv):
        return vv.customer.slug
    return f"#{vv.customer_id}"


def as_datetime(vvm: VVM, t_s: float) -> dt.datetime:
    return dt.datetime.fromtimestamp(vvm.clock.epoch_ms(t_s) / 1000, tz=dt.UTC)


def sensor_entries(names: Sequence[str], *, field: str) -> list[SensorType]:
    """The SDC entries of these names; a ValidationError on ``field`` names the unknown ones."""
    try:
        return sensors_by_name(names=names)
    except UnknownSensors as exc:
        raise ValidationError({field: str(exc)}) from None
