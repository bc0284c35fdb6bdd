"""``POST /api/v1/vvs/dry-run/`` (DESIGN.md section 9): a program tried against a simulated
copy of the fleet before anything flies (``vvm_worker.services.dry_run``); nothing is created.
"""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from drf_spectacular.utils import extend_schema
from rest_framework import generics, serializers, status
from rest_framework.exceptions import APIException, PermissionDenied, Throttled, ValidationError
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.serializers import as_serializer_error

from cpcc_site.api import Conflict, DetailSerializer
from missions.api.serializers import VVCreateSerializer
from missions.api.views import NOT_A_CUSTOMER, _refused_program
from vvm_worker.services import NotACustomer
from vvm_worker.services.dry_run import (
    DRY_RUN_WALL_S,
    DryRunBusy,
    DryRunFailed,
    DryRunReport,
    DryRunTask,
    NoGroundStation,
    vv_dry_run_for_user,
)

# Seconds a client is told to wait before it asks again when every place for a dry run is
# taken.


class DryRunUnavailable(APIException):
    """503: the simulated copy failed (nothing the program could change)."""

    status_code = status.HTTP_503_SERVICE_UNAVAILABLE
    default_code = "dry_run_unavailable"


class DryRunTaskSerializer(serializers.Serializer):
    """A task the program would ask for, as the simulated copy of the fleet served it."""

    q = serializers.IntegerField(help_text="Ordinal of the VVM-API request (as in /tasks/).")
    index = serializers.IntegerField(help_text="Index in an executeAll batch.")
    position = serializers.ListField(
        child=serializers.FloatField(), help_text="[lat, lng, alt], alt in m above ground."
    )
    tolerance_m = serializers.FloatField()
    sensors = serializers.ListField(child=serializers.CharField(), help_text="SDC entry names.")
    servable = serializers.BooleanField(help_text="Whether a vehicle in service could serve it.")
    status = serializers.ChoiceField(
        choices=["done", "rejected", "open", "cancelled"],
        help_text="done: a vehicle would read it; rejected: no vehicle in service could "
        "serve it (message says why); open: still waiting when the dry run stopped; "
        "cancelled: the program ended before it was served.",
    )
    message = serializers.CharField(help_text="Why no vehicle could serve it, if none could.")
    line = serializers.IntegerField(
        allow_null=True, help_text="Line of the VV.task.execute (or executeAll) call."
    )
    column = serializers.IntegerField(allow_null=True, help_text="Its column (1-based).")
    requested_s = serializers.FloatField(
        allow_null=True, help_text="When it would be asked for, in s from the submission."
    )
    done_s = serializers.FloatField(
        allow_null=True, help_text="When it would be read (or rejected), in s from submission."
    )


class DryRunQuotaSerializer(serializers.Serializer):
    """The quota that would stop the VV, and where."""

    quota = serializers.ChoiceField(
        choices=["tasks", "cpu", "heap", "storage", "api_calls"],
        help_text="tasks per VV, CPU time per step, V8 heap, storage bytes, allowed API calls.",
    )
    message = serializers.CharField()
    line = serializers.IntegerField(allow_null=True)
    column = serializers.IntegerField(allow_null=True)
    tasks_before = serializers.IntegerField(help_text="Tasks it had asked for before.")
    at_s = serializers.FloatField(help_text="When, in s from the submission.")


class DryRunReportSerializer(serializers.Serializer):
    """What the dry run found. Nothing was created or flown."""

    name = serializers.CharField()
    status = serializers.ChoiceField(
        choices=["finished", "failed", "killed", "unfinished"],
        help_text="How the VV would end; unfinished: the dry run reached its time limit "
        f"({DRY_RUN_WALL_S:g} s of computing) first.",
    )
    error = serializers.CharField(help_text="Why it would fail or be killed.")
    error_line = serializers.IntegerField(allow_null=True)
    error_column = serializers.IntegerField(allow_null=True)
    duration_s = serializers.FloatField(
        help_text="Estimated seconds from the submission to its end (to where the dry run "
        "stopped, when unfinished), the flights included, on what `assumes` says: the fleet "
        "in service to itself, each vehicle where it is now (in the air where its worker last "
        "reported it, else from the ground at its depot), instant readings, no wait for "
        "messages counted. Other VVs sharing the vehicles make it longer."
    )
    assumes = serializers.CharField(help_text="What duration_s assumes, in a sentence or two.")
    message_wait_s = serializers.FloatField(
        help_text="Seconds the program would wait for messages that do not come in a dry run "
        "(no other VV runs there): the timeouts of its VV.message.receive calls that got "
        "null, which duration_s leaves out. 0 for a program that waits for none."
    )
    tasks = DryRunTaskSerializer(many=True, help_text="Every task it would ask for, in order.")
    unservable = DryRunTaskSerializer(
        many=True, help_text="The tasks no vehicle in service could serve."
    )
    within_quotas = serializers.BooleanField(
        help_text="Whether it would run to its end within your quotas."
    )
    quota = DryRunQuotaSerializer(
        allow_null=True, help_text="The quota that would stop it (null: none)."
    )
    log = serializers.ListField(
        child=serializers.CharField(), help_text="The first lines the program would log."
    )


def _task_json(task: DryRunTask) -> dict[str, Any]:
    return {
        "q": task.q,
        "index": task.index,
        "position": list(task.position),
        "tolerance_m": task.tolerance_m,
        "sensors": list(task.sensors),
        "servable": task.servable,
        "status": task.status,
        "message": task.message,
        "line": task.line,
        "column": task.column,
        "requested_s": task.requested_s,
        "done_s": task.done_s,
    }


def report_json(report: DryRunReport) -> dict[str, Any]:
    """The report as DryRunReportSerializer describes it."""
    quota = report.quota
    return {
        "name": report.name,
        "status": report.status,
        "error": report.error,
        "error_line": report.error_line,
        "error_column": report.error_column,
        "duration_s": report.duration_s,
        "assumes": report.assumes,
        "message_wait_s": report.message_wait_s,
        "tasks": [_task_json(task) for task in report.tasks],
        "unservable": [_task_json(task) for task in report.unservable],
        "within_quotas": report.within_quotas,
        "quota": None
        if quota is None
        else {
            "quota": quota.quota,
            "message": quota.message,
            "line": quota.line,
            "column": quota.column,
            "tasks_before": quota.tasks_before,
            "at_s": quota.at_s,
        },
        "log": list(report.log),
    }


class DryRunView(generics.GenericAPIView):  # type: ignore[type-arg]
    """Try a program before submitting it: it runs against a simulated copy of the fleet."""

    serializer_class = VVCreateSerializer

    @extend_schema(
        request=VVCreateSerializer,
        responses={
            200: DryRunReportSerializer,
            400: DetailSerializer,
            403: DetailSerializer,
            409: DetailSerializer,
            429: DetailSerializer,
            503: DetailSerializer,
        },
        description="Run `{name, program}` against a simulated copy of the fleet (the "
        "vehicles in service, their areas, altitudes, sensors and speeds) with instant "
        "simulated readings and your quotas, and answer what it would do: every task it "
        "would ask for with the line and column of the call, those no vehicle could serve "
        "and why, how long it would take from its submission to its end (and on what "
        "assumptions: `assumes`), and whether a quota would stop it (which, and where). "
        "Nothing is created, stored or flown.\n\n"
        "400 for a program with a syntax error, as a submission would answer (`error` with "
        "the line and column) or a refused name; 409 when no VV could start at all (the "
        "platform has no ground station); 429 while this server runs as many dry runs as it "
        "may at once, while one of yours runs, or when yours used their CPU budget (try again "
        "after Retry-After); 503 when the simulation failed (the "
        "platform's fault, not the program's).",
    )
    def post(self, request: Request) -> Response:
        given = VVCreateSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        try:
            report, problem = vv_dry_run_for_user(
                user=request.user,  # type: ignore[arg-type]
                **given.validated_data,
            )
        except NotACustomer:
            raise PermissionDenied(NOT_A_CUSTOMER) from None
        except DjangoValidationError as exc:
            raise ValidationError(as_serializer_error(exc)) from None
        except DryRunBusy as exc:
            raise Throttled(wait=max(1, round(exc.retry_after_s)), detail=str(exc)) from None
        except NoGroundStation as exc:
            raise Conflict(str(exc)) from None
        except DryRunFailed as exc:
            raise DryRunUnavailable(
                f"The dry run could not be made: {exc}. Try again; the program itself was "
                "not the problem."
            ) from None
        if problem is not None:
            return Response(_refused_program(problem), status=status.HTTP_400_BAD_REQUEST)
        assert report is not None
        return Response(report_json(report))
