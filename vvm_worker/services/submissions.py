"""Several VVs submitted at once: a bulk submission of the REST API (``POST /api/v1/vvs/``
with a JSON list), all of them or none."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from django.db import transaction

from accounts.models import User
from missions.models import VirtualVehicle, vv_name_problem
from vvm_worker.runtime import SyntaxProblem, check_syntax
from vvm_worker.services.admission import vvs_queue
from vvm_worker.services.base import VVM, logger
from vvm_worker.services.vvs import NotACustomer

# Submissions one request may hold: a script that queues a whole survey at once (the issue's
# benchmark submits 200 VVs), small enough that one transaction stays short. The request body
# limit (CPCC_MAX_REQUEST_BYTES) bounds their programs' total size besides.
MAX_SUBMISSIONS = 200


@dataclass(frozen=True)
class Submission:
    """One VV to submit: its name and program."""

    name: str
    program: str


class SubmissionsRefused(ValueError):
    """Some submissions of a bulk cannot be queued (a refused name, a program with a syntax
    error), so none was: ``names`` and ``programs`` hold each refused one's problem by its
    index in the list."""

    def __init__(self, *, names: Mapping[int, str], programs: Mapping[int, SyntaxProblem]) -> None:
        self.names = dict(names)
        self.programs = dict(programs)
        refused = sorted({*self.names, *self.programs})
        super().__init__(
            f"{len(refused)} submission(s) refused (items {', '.join(map(str, refused))})"
        )


def vvs_submit_many_for_user(
    *, user: User, submissions: Sequence[Submission], vvm: VVM
) -> list[VirtualVehicle]:
    """Queue one new VV of the user's customer per submission, in one transaction: all of
    them or none.

    Every name and program is checked before anything is written, so that one answer says
    what is wrong with each. The customer's queue quota (``max_queued_vvs``) counts the whole
    list: either they all fit, or none is queued. Returns the VVs in the order of
    ``submissions``, queued: once the transaction commits, the ground-station workers are
    asked (once) to admit the customer's queued VVs within its quota of parallel VVs.

    Raises NotACustomer for a user of no customer, ValueError for an empty list or one longer
    than MAX_SUBMISSIONS, SubmissionsRefused (with each refused item's problem) and
    VVQueueFull (the quota; ``adding`` is the list's length).
    """
    if user.customer is None:
        raise NotACustomer(f"{user.username} belongs to no customer")
    if not 1 <= len(submissions) <= MAX_SUBMISSIONS:
        raise ValueError(
            f"a bulk submission holds 1 to {MAX_SUBMISSIONS} VVs, not {len(submissions)}"
        )
    names: dict[int, str] = {}
    programs: dict[int, SyntaxProblem] = {}
    for index, submission in enumerate(submissions):
        name_problem = vv_name_problem(submission.name)
        if name_problem is not None:
            names[index] = name_problem
        program_problem = check_syntax(submission.program)
        if program_problem is not None:
            programs[index] = program_problem
    if names or programs:
        raise SubmissionsRefused(names=names, programs=programs)
    customer = user.customer
    with transaction.atomic():
        # The whole list against the quota (the customer's row stays locked until the commit,
        # as for one submission), so that a list that does not fit says so as a whole.
        vvs = vvs_queue(
            customer=customer,
            named_programs=[(s.name, s.program) for s in submissions],
            vvm=vvm,
        )
        vvm.dispatcher.customer_slot_freed(customer.pk)
    logger.info(
        "vvs submitted in bulk",
        extra={"customer": customer.slug, "user": user.username, "count": len(vvs)},
    )
    return vvs
