"""What a user does with their own VVs, from the REST API and the pages: submit one or N
copies of a program, restart an ended VV with its program, edit a queued VV's program, cancel.
Each finds the VV among the user's customer's (another customer's answers as missing) and
then does what the VV's life (``vvs``) does for anyone."""

from __future__ import annotations

import uuid

from django.db import transaction

from accounts.models import Customer, User
from missions.events import vv_event
from missions.models import VirtualVehicle, VVStatus
from missions.selectors import vv_get_for_user
from vvm_worker.runtime import SyntaxProblem, check_syntax
from vvm_worker.services.admission import check_vv_name, vvs_queue
from vvm_worker.services.base import VVM, ProgramRejected, VVAlreadyEnded, logger
from vvm_worker.services.vvs import NotACustomer, VVNotEnded, VVNotQueued, vv_cancel

# Copies of one program a user may submit at once (the web editor's "copies").
MAX_COPIES = 50


def copy_names(*, name: str, copies: int) -> list[str]:
    """The names of ``copies`` copies of a VV: ``name``, ``name (2)``, ``name (3)``, ..."""
    return [name if n == 1 else f"{name} ({n})" for n in range(1, copies + 1)]


def _submit_copies(
    *, customer: Customer, name: str, program: str, copies: int, vvm: VVM
) -> list[VirtualVehicle]:
    """Queue ``copies`` VVs of one program in one transaction and, once it commits, ask the
    ground-station workers to admit the customer's queued VVs. Raises ProgramRejected for a
    syntax error (checked once; nothing is created), ValidationError for a refused name and
    VVQueueFull when the copies do not all fit the customer's queue (nothing is created)."""
    if not 1 <= copies <= MAX_COPIES:
        raise ValueError(f"copies must be between 1 and {MAX_COPIES}, not {copies}")
    check_vv_name(name)
    problem = check_syntax(program)
    if problem is not None:
        raise ProgramRejected(problem)
    with transaction.atomic():
        vvs = vvs_queue(  # all of them or none
            customer=customer,
            named_programs=[(n, program) for n in copy_names(name=name, copies=copies)],
            vvm=vvm,
        )
        vvm.dispatcher.customer_slot_freed(customer.pk)
    return vvs


def vv_create_copies_for_user(
    *, user: User, name: str, program: str, copies: int, vvm: VVM
) -> tuple[list[VirtualVehicle], SyntaxProblem | None]:
    """Queue ``copies`` (1 to MAX_COPIES) new VVs of the user's customer running one program,
    named ``name``, ``name (2)``, ``name (3)``, ... (``copy_names``); a program with a syntax
    error is refused with where the error is, and nothing is created.

    Returns the VVs in that order, queued: once the transaction that created them all commits,
    the ground-station workers are asked to admit the customer's queued VVs within its quota
    of parallel VVs (the others wait in the queue). Raises NotACustomer for a user of no
    customer and ValueError for a number of copies out of range.
    """
    if user.customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    try:
        vvs = _submit_copies(
            customer=user.customer, name=name, program=program, copies=copies, vvm=vvm
        )
    except ProgramRejected as exc:
        return [], exc.problem
    return vvs, None


def vv_create_for_user(
    *, user: User, name: str, program: str, vvm: VVM
) -> tuple[VirtualVehicle | None, SyntaxProblem | None]:
    """Queue a new VV of the user's customer, from the web or the REST API; a program with a
    syntax error is refused with where the error is (and nothing is created).

    The VV is returned queued: once the transaction commits, the ground-station workers are
    asked to admit the customer's queued VVs within its quota of parallel VVs. Raises
    NotACustomer for a user of no customer.
    """
    vvs, problem = vv_create_copies_for_user(
        user=user, name=name, program=program, copies=1, vvm=vvm
    )
    return (vvs[0] if vvs else None), problem


def vv_restart_for_user(*, user: User, vv_id: uuid.UUID | str, vvm: VVM) -> VirtualVehicle:
    """Start an ended VV (finished, failed, killed or cancelled) again: a new VV of the same
    customer with the same name and program, queued and admitted like a new submission (a new
    seed, an empty storage and log). The ended VV stays as it is.

    Staff may restart any VV (the new one belongs to the VV's customer). Raises VVNotFound for
    a missing VV or another customer's, VVNotEnded while it is queued or running, and
    ProgramRejected when its program does not parse (a scenario's VV that failed so).
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not vv.is_ended:
        raise VVNotEnded(vv)
    (new,) = _submit_copies(
        customer=vv.customer, name=vv.name, program=vv.program, copies=1, vvm=vvm
    )
    logger.info(
        "vv restarted", extra={"vv": str(new.pk), "from_vv": str(vv.pk), "user": user.username}
    )
    return new


def vv_update_program_for_user(
    *, user: User, vv_id: uuid.UUID | str, name: str, program: str, vvm: VVM
) -> VirtualVehicle:
    """Change the name and program of one of the user's VVs while it waits in the queue; it
    keeps its place there.

    Raises VVNotFound for a missing VV or another customer's, ValidationError (naming
    ``name``) for a name with a control or bidirectional formatting character,
    ProgramRejected (with the line and column) for a program with a syntax error, and
    VVNotQueued once the VV has started or ended. Returns the VV as it is afterwards.
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    check_vv_name(name)
    problem = check_syntax(program)
    if problem is not None:
        raise ProgramRejected(problem)
    with transaction.atomic():
        # Admission holds the customer's row while it starts queued VVs: taking it first (then
        # the VV's, in admission's order) means a VV starts either before the change, which is
        # then refused, or after it, with the new program.
        Customer.objects.select_for_update().filter(pk=vv.customer_id).first()
        locked = VirtualVehicle.objects.select_for_update(of=("self",), no_key=True).get(pk=vv.pk)
        if locked.status != VVStatus.QUEUED:
            raise VVNotQueued(locked)
        locked.name = name
        locked.program = program
        locked.save(update_fields=["name", "program", "updated"])
        vvm.announce(lambda: vv_event(locked))
    logger.info("vv program changed", extra={"vv": str(vv.pk), "user": user.username})
    return vv_get_for_user(user=user, vv_id=vv.pk)


def vv_cancel_for_user(*, user: User, vv_id: uuid.UUID | str, vvm: VVM) -> VirtualVehicle:
    """Cancel one of the user's VVs: its open tasks are dropped, what it stored stays.

    Raises VVNotFound for a missing VV or another customer's, and VVAlreadyEnded when it had
    already finished, failed, been killed or cancelled. Returns the VV as it is afterwards.
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not vv_cancel(vv_id=vv.pk, vvm=vvm):
        vv.refresh_from_db()
        raise VVAlreadyEnded(vv)
    return vv_get_for_user(user=user, vv_id=vv.pk)
