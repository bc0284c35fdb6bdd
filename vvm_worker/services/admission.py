"""A VV's way in: submitted into its customer's queue within the quota of queued VVs, and
admitted to a ground station (the loader) while the customer runs fewer than its quota of
parallel VVs allows, unless its service class is held back for another that misses its
target; a VV that ends frees its place (``slot_freed``)."""

from __future__ import annotations

import secrets
import uuid
from collections.abc import Sequence

from django.core.exceptions import ValidationError
from django.db import transaction
from django.db.models import F, Min, QuerySet, Value
from django.db.models.functions import Coalesce
from django.utils import timezone

from accounts.models import Customer
from accounts.selectors import customer_catalog
from fleet.models import GroundStation
from missions.events import vv_event
from missions.models import (
    ACTIVE_STATUSES,
    VirtualVehicle,
    VVStatus,
    WaitReason,
    vv_name_problem,
)
from missions.selectors import customer_has_queued_vv
from vvm_worker.dispatch import HostRef
from vvm_worker.runtime import (
    check_syntax,
)
from vvm_worker.services.base import (
    VVM,
    ProgramRejected,
    ground_stations_loaded,
    logger,
)
from vvm_worker.services.service_levels import (
    class_held_nudge,
    holding_back,
    service_level_hold_end,
    service_level_hold_keep,
)


class VVQueueFull(RuntimeError):
    """The customer's queue holds as many VVs as its quota allows (``max_queued_vvs``), so no
    more can be submitted until some start or are cancelled."""

    def __init__(self, customer: Customer, *, queued: int, adding: int) -> None:
        more = "one more" if adding == 1 else f"{adding} more"
        super().__init__(
            f"{customer.name} has {queued} VV(s) waiting in the queue and may have at most "
            f"{customer.max_queued_vvs} (its quota max_queued_vvs), so {more} cannot be "
            "submitted now: wait until some of them start, or cancel some, then submit again."
        )
        self.customer = customer
        self.queued = queued
        self.adding = adding


# Steps one host runs for one VV before it lets other work go first (rejected tasks in a row).


def vv_submit(
    *,
    customer: Customer,
    name: str,
    program: str,
    vvm: VVM,
    seed: int | None = None,
    vv_id: uuid.UUID | None = None,
    refuse_syntax_errors: bool = True,
    admit: bool = True,
) -> VirtualVehicle:
    """Queue a new VV for the customer and, with ``admit``, start it if the quota allows.

    Raises ProgramRejected for a syntax error unless ``refuse_syntax_errors`` is False (a
    scenario's VV then ends ``failed`` with the line and column when it is loaded),
    ValidationError (naming ``name``) for a name with a control or bidirectional formatting
    character, and VVQueueFull when the customer's queue is full (``max_queued_vvs``; every
    submission counts: the API's, the editor's, a restart, a scenario's).
    """
    check_vv_name(name)
    if refuse_syntax_errors:
        problem = check_syntax(program)
        if problem is not None:
            raise ProgramRejected(problem)
    now = vvm.clock.now_s()
    with transaction.atomic():
        _check_queue(customer, adding=1)
        vv = VirtualVehicle.objects.create(
            id=vv_id or uuid.uuid4(),
            customer=customer,
            name=name,
            program=program,
            seed=secrets.randbits(31) if seed is None else seed,
            start_ms=vvm.clock.epoch_ms(now),
            catalog=customer_catalog(customer=customer),
            submitted_s=now,
        )
    logger.info("vv submitted", extra={"vv": str(vv.id), "customer": customer.slug})
    vvm.announce(lambda: vv_event(vv))
    if admit:
        for admitted in _admit(customer.pk, vvm):  # (one is queued: this one)
            if admitted.pk == vv.pk:  # as admission changed it
                vv.status, vv.host_gs, vv.started_s = (
                    admitted.status,
                    admitted.host_gs,
                    admitted.started_s,
                )
                vv.updated = admitted.updated
    return vv


def vvs_queue(
    *, customer: Customer, named_programs: Sequence[tuple[str, str]], vvm: VVM
) -> list[VirtualVehicle]:
    """Queue new VVs of the customer (a name and a checked program each) in the caller's
    transaction, all at once: one check of the queue quota for all of them (VVQueueFull:
    none is queued), one read of the customer's catalog, one insert. The caller asks for
    their admission once it commits (``Dispatcher.customer_slot_freed``)."""
    for name, _ in named_programs:
        check_vv_name(name)
    _check_queue(customer, adding=len(named_programs))
    now = vvm.clock.now_s()
    catalog = customer_catalog(customer=customer)
    vvs = VirtualVehicle.objects.bulk_create(
        VirtualVehicle(
            id=uuid.uuid4(),
            customer=customer,
            name=name,
            program=program,
            seed=secrets.randbits(31),
            start_ms=vvm.clock.epoch_ms(now),
            catalog=catalog,
            submitted_s=now,
        )
        for name, program in named_programs
    )
    for vv in vvs:
        logger.info("vv submitted", extra={"vv": str(vv.id), "customer": customer.slug})
    vvm.announce(lambda: [vv_event(vv) for vv in vvs])
    return vvs


def check_vv_name(name: str) -> None:
    problem = vv_name_problem(name)
    if problem is not None:
        raise ValidationError({"name": [problem]})


def _check_queue(customer: Customer, *, adding: int) -> None:
    """Raise VVQueueFull unless ``adding`` more queued VVs fit the customer's quota. Holds the
    customer's row until the transaction ends, as admission does, so that two submissions at
    once cannot both take the last place."""
    locked = Customer.objects.select_for_update().get(pk=customer.pk)
    queued = VirtualVehicle.objects.filter(customer=locked, status=VVStatus.QUEUED).count()
    if queued + adding > locked.max_queued_vvs:
        raise VVQueueFull(locked, queued=queued, adding=adding)


def vv_admit_queued(*, customer_id: int, vvm: VVM) -> list[VirtualVehicle]:
    """Start the customer's oldest queued VVs while it runs fewer than its quota allows,
    unless admission holds back its class for another that misses its target now: then none
    starts and each says why it is held (``WaitReason.SERVICE_LEVEL``) until a later pass
    ends the hold (a task of a class ends: ``class_held_nudge``; a ground station's sweep)."""
    if not customer_has_queued_vv(customer_id=customer_id):
        return []  # nothing waits (a VV that is queued later asks again)
    return _admit(customer_id, vvm)


def _admit(customer_id: int, vvm: VVM) -> list[VirtualVehicle]:
    with transaction.atomic():
        customer = Customer.objects.select_for_update().filter(pk=customer_id).first()
        if customer is None:  # a late message about a customer that was deleted
            return []
        running = VirtualVehicle.objects.filter(customer=customer, status__in=ACTIVE_STATUSES)
        free = customer.max_parallel_vvs - running.count()
        if free <= 0:
            return []
        queued = VirtualVehicle.objects.filter(customer=customer, status=VVStatus.QUEUED)
        if _held_by_service_level(customer, queued, vvm):
            return []
        admitted = list(queued.order_by("submitted_s", "created", "id")[:free])
        if not admitted:
            return []
        # Each to the ground station holding the fewest VVs (counting those admitted before
        # it), as ground_station_for would say one after the other: one read for all.
        stations = ground_stations_loaded()
        if not stations:
            first = admitted[0]
            logger.warning("no ground station: VV stays queued", extra={"vv": str(first.id)})
            return []
        now, stamp = vvm.clock.now_s(), timezone.now()
        by_station: dict[GroundStation, list[uuid.UUID]] = {}
        for vv in admitted:
            gs = min(stations, key=lambda gs: (gs.load, gs.name))
            gs.load += 1
            vv.status, vv.host_gs, vv.started_s, vv.updated = VVStatus.RUNNING, gs, now, stamp
            by_station.setdefault(gs, []).append(vv.pk)
        for gs, ids in by_station.items():  # one UPDATE a station
            VirtualVehicle.objects.filter(pk__in=ids).update(
                status=VVStatus.RUNNING, host_gs=gs, started_s=now, updated=stamp
            )
        for vv in admitted:
            vvm.announce(lambda vv=vv: vv_event(vv))
            vvm.dispatcher.vv_arrived(vv.id, on=HostRef(gs_id=vv.host_gs_id))
        return admitted


def _held_by_service_level(customer: Customer, queued: QuerySet[VirtualVehicle], vvm: VVM) -> bool:
    """Whether admission holds back the customer's ``queued`` VVs for another class that
    misses its target (``service_levels.holding_back``): their rows say so in the customer's
    words (one UPDATE) and the customer's hold is recorded for the service-level report. Once
    the hold ends (the other class keeps its target again, or this one has used its slack),
    those held before are plain queued VVs again and the hold has ended. A customer without a
    class is never held (and costs no query)."""
    if customer.service_class_id is None:
        return False
    now = vvm.clock.now_s()
    hold = holding_back(service_class=customer.service_class, now_s=now)
    if hold is not None:
        since = queued.filter(waiting_reason=WaitReason.SERVICE_LEVEL).aggregate(
            since=Min("waiting_since_s")
        )["since"]
        if hold.used_up(held_since_s=since, now_s=now):
            hold = None
    if hold is None:
        queued.filter(waiting_reason=WaitReason.SERVICE_LEVEL).update(
            waiting_reason="", waiting_message="", waiting_since_s=None
        )
        service_level_hold_end(customer_id=customer.pk, now_s=now)
        return False
    held = queued.update(
        waiting_reason=WaitReason.SERVICE_LEVEL,
        waiting_message=hold.message(),
        waiting_since_s=Coalesce(F("waiting_since_s"), Value(now)),
    )
    service_level_hold_keep(customer_id=customer.pk, hold=hold, held=held, now_s=now)
    logger.info(
        "vvs held back for other service levels",
        extra={
            "customer": customer.slug,
            "service_class": hold.level.spec.name,
            "p95_s": hold.level.p95_s,
            "for_classes": ",".join(hold.for_classes),
            "held": held,
        },
    )
    return True


def slot_freed(vv: VirtualVehicle, vvm: VVM) -> None:
    """A VV of the customer that ran ended: admit its queued ones, and (its open tasks end
    with it) look again at the VVs of its class held for the class's target."""
    vvm.dispatcher.customer_slot_freed(vv.customer_id)
    class_held_nudge(service_class_id=vv.customer.service_class_id, vvm=vvm, told=vv.customer_id)
