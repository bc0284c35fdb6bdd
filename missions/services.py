"""Customer actions on VVs: submitting one through the web or the REST API."""

from __future__ import annotations

from accounts.models import User
from fleet.simulation import SensorField
from missions.models import VirtualVehicle
from vvm_worker.clock import SystemClock
from vvm_worker.dispatch import NullDispatcher
from vvm_worker.runtime import SyntaxProblem
from vvm_worker.services import VVM, ProgramRejected, vv_submit


class NotACustomer(PermissionError):
    """The user belongs to no customer, so it cannot own VVs."""


def vv_create_for_user(
    *, user: User, name: str, program: str
) -> tuple[VirtualVehicle | None, SyntaxProblem | None]:
    """Queue the user's customer's new VV; a program with a syntax error is refused with
    where the error is. The ground-station workers admit queued VVs within the quota."""
    if user.customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    vvm = VVM(clock=SystemClock(), dispatcher=NullDispatcher(), field=SensorField(0))
    try:
        vv = vv_submit(customer=user.customer, name=name, program=program, vvm=vvm, admit=False)
    except ProgramRejected as exc:
        return None, exc.problem
    return vv, None
