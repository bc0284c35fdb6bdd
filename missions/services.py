"""Customer actions on VVs through the web or the REST API: submitting and cancelling one."""

from __future__ import annotations

import uuid

from django.db import transaction

from accounts.models import User
from missions.models import VirtualVehicle
from missions.selectors import vv_get_for_user
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import SyntaxProblem
from vvm_worker.services import ProgramRejected, vv_cancel, vv_submit


class NotACustomer(PermissionError):
    """The user belongs to no customer, so it cannot own VVs."""


class VVAlreadyEnded(RuntimeError):
    """The VV had already ended, so there is nothing to cancel."""

    def __init__(self, vv: VirtualVehicle) -> None:
        super().__init__(f"{vv.name} has already ended ({vv.status})")
        self.vv = vv


def vv_create_for_user(
    *, user: User, name: str, program: str
) -> tuple[VirtualVehicle | None, SyntaxProblem | None]:
    """Queue the user's customer's new VV; a program with a syntax error is refused with
    where the error is (and nothing is created).

    The VV is returned queued: once the transaction commits, the ground-station workers are
    asked to admit the customer's queued VVs within its quota of parallel VVs.
    """
    if user.customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    vvm = platform_vvm()
    try:
        with transaction.atomic():
            vv = vv_submit(customer=user.customer, name=name, program=program, vvm=vvm, admit=False)
            vvm.dispatcher.customer_slot_freed(user.customer.pk)
    except ProgramRejected as exc:
        return None, exc.problem
    return vv, None


def vv_cancel_for_user(*, user: User, vv_id: uuid.UUID | str) -> VirtualVehicle:
    """Cancel one of the user's VVs: its open tasks are dropped, what it stored stays.

    Raises VVNotFound for a missing VV or another customer's, and VVAlreadyEnded when it had
    already finished, failed, been killed or cancelled. Returns the VV as it is afterwards.
    """
    vv = vv_get_for_user(user=user, vv_id=vv_id)
    if not vv_cancel(vv_id=vv.pk, vvm=platform_vvm()):
        vv.refresh_from_db()
        raise VVAlreadyEnded(vv)
    return vv_get_for_user(user=user, vv_id=vv.pk)
