"""The simulated copy of the fleet a dry run flies (``vvm_worker.services.dry_run`` says what a
dry run is and why its copy runs in a process of its own: ``manage.py dry_run_copy FOLDER``).

That process's default database is a new SQLite file: ``prepare_database`` gives it the
platform's schema, ``run_copy`` loads the fleet (a scenario document) and the customer's quotas
and runs ``manage.py simulate``'s simulation on discrete-event time until the VV ends or the
wall-clock limit is reached, and reports what it saw.

Two things differ from the platform, so that the duration the report gives is the program's
own (``DryRunReport.assumes`` tells the customer what it counts):

- no other VV runs in it, so no message can come: ``VV.message.receive`` answers null at once
  instead of waiting its timeout for nothing (the report's ``message_wait_s`` adds those up);
- a camera's picture is drawn, as on the platform, so that the program can look at it with
  ``VV.image.*``; it goes into the copy's own media folder (``CPCC_MEDIA_ROOT`` of the
  process), which is thrown away with it.

The copy's database starts as a copy of a database migrated once per version of the
migrations (``vvm_worker.fresh_database``).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from django.conf import settings

from accounts.models import Customer
from fleet.models import SensorType
from missions.models import ENDED_STATUSES, JournalEntry, LogEntry, Task, VirtualVehicle
from vvm_worker.runtime import ErrorKind, Outcome, Runtime, StepInput, StepResult, VVError
from vvm_worker.scenario import parse_scenario
from vvm_worker.services.dry_run import (
    COPY_CUSTOMER,
    UNFINISHED,
    DryRunReport,
    DryRunTask,
    QuotaStop,
)
from vvm_worker.simulation import Simulation

# The first lines the program logs go in the report (a dry run's log is to look at, not keep).
MAX_LOG_LINES = 200


# --- the run ------------------------------------------------------------------------------------


class _Recorder(Runtime):
    """The copy's runtime: the platform's, noting where in the program each request was made
    (by its ordinal) and how the VV ended. A ``VV.message.receive`` is made to wait no time
    (no other VV runs in the copy to send a message); its timeout is noted by its ordinal."""

    def __init__(self, *, max_contexts: int) -> None:
        super().__init__(max_contexts=max_contexts)
        self.places: dict[int, tuple[int | None, int | None]] = {}
        self.receive_timeouts: dict[int, float] = {}
        self.error: VVError | None = None
        self.ended = False

    def step(self, step: StepInput) -> StepResult:
        result = super().step(step)
        pending = result.pending
        if pending is not None:
            self.places.setdefault(pending.q, (pending.line, pending.column))
            if pending.kind == "message" and pending.timeout_s:
                # The host reads the timeout from the pending request when it first answers
                # it (vv_answer_receive): with 0, a message there already is still taken.
                self.receive_timeouts[pending.q] = pending.timeout_s
                pending = dataclasses.replace(pending, timeout_s=0.0)
                result = dataclasses.replace(result, pending=pending)
        if result.outcome is not Outcome.SUSPENDED:
            self.ended = True
            self.error = result.error
        return result


def run_copy(request: Mapping[str, Any]) -> DryRunReport:
    """Run the request's ``scenario`` (the fleet and one VV of COPY_CUSTOMER, who gets the
    request's ``customer`` quotas) on the default database until the VV ends or ``wall_s``
    seconds of wall-clock time have passed, and report it."""
    settings.DEBUG = False  # no statement log (this process is the copy's alone)
    scenario = parse_scenario(request["scenario"], base_dir=Path.cwd())
    simulation = Simulation(scenario, seed=1, speed=0.0, logins=False)
    recorder = _Recorder(max_contexts=4)
    simulation.vvm.runtime = recorder
    loaded = simulation.start()  # the VV is submitted by the first event
    _give_quotas(loaded.customers[COPY_CUSTOMER], request["customer"])
    deadline = time.monotonic() + float(request["wall_s"])
    simulation.drain(until=lambda: recorder.ended or time.monotonic() > deadline)
    (vv,) = VirtualVehicle.objects.filter(pk__in=simulation.vv_ids)
    return _report(vv, recorder, now_s=simulation.clock.t)


def _give_quotas(customer: Customer, quotas: Mapping[str, Any]) -> None:
    """The real customer's quotas, SDC entries and VVM-API calls on the copy's customer."""
    fields = {key: value for key, value in quotas.items() if key != "allowed_sensors"}
    Customer.objects.filter(pk=customer.pk).update(**fields)
    customer.allowed_sensors.set(SensorType.objects.filter(name__in=quotas["allowed_sensors"]))


def _report(vv: VirtualVehicle, recorder: _Recorder, *, now_s: float) -> DryRunReport:
    tasks = []
    for task in Task.objects.filter(vv=vv).order_by("q", "index"):
        line, column = recorder.places.get(task.q, (None, None))
        tasks.append(
            DryRunTask(
                q=task.q,
                index=task.index,
                position=(task.lat, task.lng, task.alt),
                tolerance_m=task.tolerance_m,
                sensors=tuple(task.sensors),
                status=task.status,
                message=task.message,
                line=line,
                column=column,
                requested_s=_since(vv, task.requested_s),
                done_s=_since(vv, task.done_s),
            )
        )
    ended = vv.status in ENDED_STATUSES
    end_s = vv.finished_s if ended and vv.finished_s is not None else now_s
    error = recorder.error
    quota = None
    if error is not None and error.kind is ErrorKind.QUOTA:
        quota = QuotaStop(
            quota=error.quota or "",
            message=error.message,
            line=error.line,
            column=error.column,
            tasks_before=len(tasks),
            at_s=round(end_s - vv.submitted_s, 3),
        )
    log = LogEntry.objects.filter(vv=vv, seq__isnull=False).order_by("seq")
    return DryRunReport(
        name=vv.name,
        status=vv.status if ended else UNFINISHED,
        error=vv.error if ended else "",
        error_line=vv.error_line if ended else None,
        error_column=vv.error_column if ended else None,
        duration_s=round(end_s - vv.submitted_s, 3),
        tasks=tuple(tasks),
        quota=quota,
        log=tuple(log.values_list("message", flat=True)[:MAX_LOG_LINES]),
        message_wait_s=_message_wait_s(vv, recorder),
    )


def _message_wait_s(vv: VirtualVehicle, recorder: _Recorder) -> float:
    """The timeouts of the receives the copy answered with null (no message came): how long
    the program would have waited for messages that do not come in a dry run."""
    if not recorder.receive_timeouts:
        return 0.0
    unanswered = [
        entry["q"]
        for entry in JournalEntry.objects.filter(vv=vv).values_list("entry", flat=True)
        if entry.get("k") == "msg" and entry.get("data") is None
    ]
    return round(sum(recorder.receive_timeouts.get(q, 0.0) for q in unanswered), 3)


def _since(vv: VirtualVehicle, t_s: float | None) -> float | None:
    """A time of the copy as seconds from the VV's submission."""
    return None if t_s is None else round(t_s - vv.submitted_s, 3)
