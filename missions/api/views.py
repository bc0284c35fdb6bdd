"""The VV endpoints of the REST API (DESIGN.md section 6), always scoped to the caller.

Another customer's VV answers 404, exactly like one that does not exist.
"""

from __future__ import annotations

import mimetypes
from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from django.core.files.storage import default_storage
from django.db.models import QuerySet
from django.http import FileResponse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import (
    OpenApiParameter,
    PolymorphicProxySerializer,
    extend_schema,
    extend_schema_view,
)
from rest_framework import generics, mixins, status, viewsets
from rest_framework.decorators import action
from rest_framework.exceptions import NotFound, PermissionDenied, ValidationError
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.serializers import BaseSerializer, as_serializer_error

from cpcc_site.api import (
    Conflict,
    DetailSerializer,
    FileOrJSONNegotiation,
    QuotaReached,
    error_body,
)
from missions.api.results import build_results_zip, results_filename
from missions.api.serializers import (
    LogEntryOutSerializer,
    StaffTaskOutSerializer,
    StorageDocumentOutSerializer,
    TaskOutSerializer,
    VVCreateSerializer,
    VVSerializer,
)
from missions.models import LogEntry, StorageDocument, Task, VirtualVehicle, VVStatus
from missions.readings import image_file, is_camera_reading
from missions.selectors import (
    ImageNotFound,
    StorageKeyNotFound,
    VVNotFound,
    vv_get_for_user,
    vv_image_for_user,
    vv_list_for_user,
    vv_log_for_user,
    vv_log_pages_for_user,
    vv_pages_for_user,
    vv_storage_for_user,
    vv_storage_get_for_user,
    vv_storage_pages_for_user,
    vv_tasks_for_user,
    vvs_listed,
    with_task_counts,
)
from vvm_worker.platform import platform_vvm
from vvm_worker.runtime import SyntaxProblem
from vvm_worker.services import (
    MAX_SUBMISSIONS,
    NotACustomer,
    Submission,
    SubmissionsRefused,
    VVAlreadyEnded,
    VVQueueFull,
    vv_cancel_for_user,
    vv_create_for_user,
    vvs_submit_many_for_user,
)

NO_SUCH_VV = (
    "No virtual vehicle with this id among yours: check the id (GET /api/v1/vvs/ lists them)."
)
VV_ID = OpenApiParameter("id", OpenApiTypes.UUID, OpenApiParameter.PATH, description="The VV's id.")
NOT_FOUND = {404: DetailSerializer}
# A VV's id in a path: anything else is no route at all (404), never a database error.
UUID_PATTERN = "[0-9a-fA-F]{8}-?[0-9a-fA-F]{4}-?[0-9a-fA-F]{4}-?[0-9a-fA-F]{4}-?[0-9a-fA-F]{12}"
IMAGE = {(200, "image/png"): OpenApiTypes.BINARY, (200, "image/jpeg"): OpenApiTypes.BINARY}
NOT_A_CUSTOMER = "Only a customer's users can submit VVs."
# POST /api/v1/vvs/ takes one submission or a list of them (DESIGN.md section 9), and answers
# in the same form.
SUBMISSIONS = PolymorphicProxySerializer(
    component_name="VVSubmission",
    serializers=[
        VVCreateSerializer,
        VVCreateSerializer(many=True, min_length=1, max_length=MAX_SUBMISSIONS),
    ],
    resource_type_field_name=None,
    many=False,
)


def submission_list_bounds(result: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    """drf-spectacular postprocessing hook: a list of submissions holds 1 to MAX_SUBMISSIONS
    (the list serializer's lengths, which drf-spectacular does not write)."""
    for form in (
        result.get("components", {}).get("schemas", {}).get("VVSubmission", {}).get("oneOf", ())
    ):
        if form.get("type") == "array":
            form.update(minItems=1, maxItems=MAX_SUBMISSIONS)
    return result


SUBMITTED = PolymorphicProxySerializer(
    component_name="VVSubmitted",
    serializers=[VVSerializer, VVSerializer(many=True)],
    resource_type_field_name=None,
    many=False,
)


class VVErrorsMixin:
    """Turns the domain's "not found", "already ended", "queue full" and refused values into
    JSON errors a person can act on."""

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, VVNotFound):
            exc = NotFound(NO_SUCH_VV)
        elif isinstance(exc, StorageKeyNotFound):
            exc = NotFound(
                f"This VV's storage has no key {exc.args[0]!r} "
                "(GET /api/v1/vvs/{id}/storage/ lists its keys)."
            )
        elif isinstance(exc, ImageNotFound):
            exc = NotFound(f"No reading of this VV took a picture named {exc.args[0]!r}.")
        elif isinstance(exc, VVAlreadyEnded):
            exc = Conflict(
                f"{exc.vv.name!r} has already ended ({exc.vv.status}): there is nothing to cancel."
            )
        elif isinstance(exc, VVQueueFull):
            exc = QuotaReached(str(exc))
        elif isinstance(exc, DjangoValidationError):
            exc = ValidationError(as_serializer_error(exc))
        return super().handle_exception(exc)  # type: ignore[misc, no-any-return]


def _refused_program(problem: SyntaxProblem) -> dict[str, Any]:
    """The 400 body of a submission whose program has a syntax error: where it is."""
    error = {"message": problem.message, "line": problem.line, "column": problem.column}
    return {"detail": f"program: {problem}", "program": [str(problem)], "error": error}


def _refused_items(errors: list[dict[str, Any]]) -> Response:
    """400 for a bulk submission of which some items are refused (nothing was created):
    ``errors`` has one entry per item, ``{}`` for those that were fine."""
    refused = [index for index, error in enumerate(errors) if error]
    more = f" (and {len(refused) - 1} more item(s))" if len(refused) > 1 else ""
    detail = (
        f"item {refused[0]}: {errors[refused[0]]['detail']}{more}. Nothing was submitted: "
        "correct the items that 'errors' names and send the list again."
    )
    return Response({"detail": detail, "errors": errors}, status=status.HTTP_400_BAD_REQUEST)


def _fields(errors: dict[str, Any] | list[Any]) -> dict[str, Any]:
    return errors if isinstance(errors, dict) else {"non_field_errors": errors}


def _image_response(reference: str) -> FileResponse:
    """The picture a reading references, from the platform's media storage."""
    try:
        handle = default_storage.open(reference, "rb")
    except OSError:
        raise NotFound("The picture of this reading is no longer kept by the platform.") from None
    content_type = mimetypes.guess_type(reference)[0] or "application/octet-stream"
    response = FileResponse(handle, content_type=content_type, filename=image_file(reference))
    # Content-addressed: a file name always means the same bytes. Private: tenancy.
    response["Cache-Control"] = "private, max-age=86400"
    return response


@extend_schema_view(
    list=extend_schema(
        parameters=[
            OpenApiParameter("status", enum=VVStatus.values, description="only VVs in this state")
        ]
    ),
    retrieve=extend_schema(responses={200: VVSerializer, **NOT_FOUND}),
)
class VirtualVehicleViewSet(
    VVErrorsMixin, mixins.ListModelMixin, mixins.RetrieveModelMixin, viewsets.GenericViewSet
):
    """Your virtual vehicles: submit a program, list them, look at one, cancel one.

    Another customer's VV answers 404, like one that does not exist.
    """

    serializer_class = VVSerializer
    lookup_value_regex = UUID_PATTERN

    def get_queryset(self) -> QuerySet[VirtualVehicle]:
        vvs = vvs_listed(vv_list_for_user(user=self.request.user)).order_by("-created")  # type: ignore[arg-type]
        wanted = self._status_wanted()
        return vvs.filter(status=wanted) if wanted else vvs

    def _status_wanted(self) -> str | None:
        """The ``status`` the list is asked for (None: all); a 400 for one that is none."""
        wanted = self.request.query_params.get("status")
        if wanted is not None and wanted not in VVStatus.values:
            raise ValidationError(
                {"status": [f"{wanted!r} is not a status; one of {', '.join(VVStatus.values)}."]}
            )
        return wanted or None

    def get_object(self) -> VirtualVehicle:
        return vv_get_for_user(user=self.request.user, vv_id=self.kwargs["pk"])  # type: ignore[arg-type]

    def list(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        # The queryset's pages, each read with SQL written once (vv_pages_for_user).
        vvs = vv_pages_for_user(user=request.user, status=self._status_wanted())  # type: ignore[arg-type]
        page = self.paginate_queryset(vvs)  # type: ignore[arg-type]
        assert page is not None, "the API paginates every list"
        with_task_counts(page)  # the page's VVs' tasks, counted at once
        return self.get_paginated_response(self.get_serializer(page, many=True).data)

    @extend_schema(
        request=SUBMISSIONS,
        responses={201: SUBMITTED, 429: DetailSerializer},
        description="Queue a new VV: `{name, program}` answers the VV. 400 for a program with "
        "a syntax error (with its line and column) or a refused name; 429 when your queue of "
        "VVs waiting to start is full (the customer's max_queued_vvs) or a request rate is "
        "passed.\n\n"
        f"Several at once: a list of 1 to {MAX_SUBMISSIONS} `{{name, program}}` answers the "
        "list of VVs in the same order. It is one transaction: all of them are queued or none. "
        "When any item is refused, the answer is 400 with `errors`, one entry per item in "
        "order: `{}` for an item that was fine, otherwise the body a single submission of that "
        "item would get (`program` and `error` with the line and column, or the refused "
        "field). The quota counts the whole list: 429 when it does not all fit.",
    )
    def create(self, request: Request) -> Response:
        if isinstance(request.data, list):
            return self._create_many(request, request.data)
        given = VVCreateSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        try:
            vv, problem = vv_create_for_user(
                user=request.user,  # type: ignore[arg-type]
                vvm=platform_vvm(),
                **given.validated_data,
            )
        except NotACustomer:
            raise PermissionDenied(NOT_A_CUSTOMER) from None
        if problem is not None:
            return Response(_refused_program(problem), status=status.HTTP_400_BAD_REQUEST)
        # Just created: no task yet (not two counts to say so).
        vv.tasks_done = vv.tasks_open = 0  # type: ignore[attr-defined]
        return Response(self.get_serializer(vv).data, status=status.HTTP_201_CREATED)

    def _create_many(self, request: Request, items: list[Any]) -> Response:
        """A bulk submission: every item checked, then all queued in one transaction."""
        if not 1 <= len(items) <= MAX_SUBMISSIONS:
            detail = (
                f"A list holds 1 to {MAX_SUBMISSIONS} submissions, this one {len(items)}: "
                f"send them in several requests of at most {MAX_SUBMISSIONS}."
            )
            return Response({"detail": detail}, status=status.HTTP_400_BAD_REQUEST)
        given = VVCreateSerializer(data=items, many=True)
        if not given.is_valid():
            # DRF gives the refused items' errors by their index (older versions: a list), an
            # item's as a list of messages when it is not an object at all (null).
            found = given.errors
            by_index = found if isinstance(found, dict) else dict(enumerate(found))
            return _refused_items(
                [
                    error_body(_fields(by_index[i])) if by_index.get(i) else {}
                    for i in range(len(items))
                ]
            )
        submissions = [Submission(**item) for item in given.validated_data]
        try:
            vvs = vvs_submit_many_for_user(
                user=request.user,  # type: ignore[arg-type]
                submissions=submissions,
                vvm=platform_vvm(),
            )
        except NotACustomer:
            raise PermissionDenied(NOT_A_CUSTOMER) from None
        except SubmissionsRefused as refused:
            errors: list[dict[str, Any]] = [{} for _ in items]
            for index, problem in refused.names.items():
                errors[index] = error_body({"name": [problem]})
            for index, syntax in refused.programs.items():
                errors[index] = {**_refused_program(syntax), **errors[index]}
            return _refused_items(errors)
        for vv in vvs:
            vv.tasks_done = vv.tasks_open = 0  # type: ignore[attr-defined]
        return Response(self.get_serializer(vvs, many=True).data, status=status.HTTP_201_CREATED)

    @extend_schema(
        request=None,
        responses={200: VVSerializer, **NOT_FOUND, 409: DetailSerializer},
        description="Stop the VV: its open tasks are dropped, what it stored stays. "
        "409 when it had already ended.",
    )
    @action(detail=True, methods=["post"])
    def cancel(self, request: Request, pk: str, format: str | None = None) -> Response:
        # ``format``: the router's suffix route (.../cancel.json) passes it.
        vv = vv_cancel_for_user(user=request.user, vv_id=pk, vvm=platform_vvm())  # type: ignore[arg-type]
        return Response(self.get_serializer(vv).data)


@extend_schema(
    parameters=[VV_ID], responses={200: StorageDocumentOutSerializer(many=True), **NOT_FOUND}
)
class VVStorageListView(VVErrorsMixin, generics.ListAPIView):  # type: ignore[type-arg]
    """The VV's storage: every key with its value. A camera reading in a value (at any depth)
    also has ``image_url``, where its picture is."""

    serializer_class = StorageDocumentOutSerializer

    def get_queryset(self) -> QuerySet[StorageDocument]:
        return vv_storage_for_user(user=self.request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]

    def list(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        # The queryset's pages, each read with SQL written once.
        docs = vv_storage_pages_for_user(user=request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]
        page = self.paginate_queryset(docs)  # type: ignore[arg-type]
        assert page is not None, "the API paginates every list"
        return self.get_paginated_response(self.get_serializer(page, many=True).data)


@extend_schema(
    parameters=[
        VV_ID,
        OpenApiParameter(
            "key",
            OpenApiTypes.STR,
            OpenApiParameter.PATH,
            description="The storage key, percent-encoded (it may contain '/', '.', spaces...).",
        ),
        OpenApiParameter(
            "format",
            OpenApiTypes.STR,
            enum=["json"],
            description="json: the document as JSON even when the value is a camera reading.",
        ),
    ],
    responses={200: StorageDocumentOutSerializer, **IMAGE, **NOT_FOUND},
)
class VVStorageItemView(VVErrorsMixin, generics.GenericAPIView):  # type: ignore[type-arg]
    """One key of the VV's storage as ``{key, value, updated}``, or, when the value is itself a
    camera reading, its picture (PNG or JPEG); ``?format=json`` gives the JSON anyway."""

    serializer_class = StorageDocumentOutSerializer
    content_negotiation_class = FileOrJSONNegotiation

    def get(self, request: Request, id: str, key: str) -> Response | FileResponse:
        doc = vv_storage_get_for_user(user=request.user, vv_id=id, key=key)  # type: ignore[arg-type]
        if is_camera_reading(doc.value) and request.query_params.get("format") != "json":
            reference = vv_image_for_user(
                user=request.user,  # type: ignore[arg-type]
                vv_id=id,
                file=image_file(doc.value["image"]),
            )
            return _image_response(reference)
        return Response(self.get_serializer(doc).data)


@extend_schema(
    parameters=[
        VV_ID,
        OpenApiParameter(
            "file", OpenApiTypes.STR, OpenApiParameter.PATH, description="The image's file name."
        ),
    ],
    responses={**IMAGE, **NOT_FOUND},
)
class VVImageView(VVErrorsMixin, generics.GenericAPIView):  # type: ignore[type-arg]
    """A picture one of the VV's camera readings took (the ``image_url`` of the reading)."""

    content_negotiation_class = FileOrJSONNegotiation

    def get_serializer_class(self) -> type[BaseSerializer[Any]]:
        return DetailSerializer  # only errors are JSON here

    def get(self, request: Request, id: str, file: str) -> FileResponse:
        reference = vv_image_for_user(user=request.user, vv_id=id, file=file)  # type: ignore[arg-type]
        return _image_response(reference)


@extend_schema(parameters=[VV_ID], responses={200: TaskOutSerializer(many=True), **NOT_FOUND})
class VVTaskListView(VVErrorsMixin, generics.ListAPIView):  # type: ignore[type-arg]
    """The VV's tasks in the order it asked for them, with their readings once done (camera
    readings have ``image_url``) and why a rejected one was rejected. Staff also see
    ``vehicle``, the name of the RV that served or serves the task."""

    def get_serializer_class(self) -> type[TaskOutSerializer]:
        return StaffTaskOutSerializer if self.request.user.is_staff else TaskOutSerializer

    def get_queryset(self) -> QuerySet[Task]:
        return vv_tasks_for_user(user=self.request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]


@extend_schema(parameters=[VV_ID], responses={200: LogEntryOutSerializer(many=True), **NOT_FOUND})
class VVLogView(VVErrorsMixin, generics.ListAPIView):  # type: ignore[type-arg]
    """The VV's log, oldest line first: what its program logged and what the platform said."""

    serializer_class = LogEntryOutSerializer

    def get_queryset(self) -> QuerySet[LogEntry]:
        return vv_log_for_user(user=self.request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]

    def list(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        # The queryset's pages, each read with SQL written once.
        lines = vv_log_pages_for_user(user=request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]
        page = self.paginate_queryset(lines)  # type: ignore[arg-type]
        assert page is not None, "the API paginates every list"
        return self.get_paginated_response(self.get_serializer(page, many=True).data)


@extend_schema(
    parameters=[VV_ID], responses={(200, "application/zip"): OpenApiTypes.BINARY, **NOT_FOUND}
)
class VVResultsView(VVErrorsMixin, generics.GenericAPIView):  # type: ignore[type-arg]
    """Everything the VV produced as one zip: ``vv.json``, ``storage.json`` (camera readings
    name their file under ``images/``), ``tasks.json``, ``log.txt`` and ``images/``."""

    content_negotiation_class = FileOrJSONNegotiation

    def get_serializer_class(self) -> type[BaseSerializer[Any]]:
        return DetailSerializer  # only errors are JSON here

    def get(self, request: Request, id: str) -> FileResponse:
        vv = vv_get_for_user(user=request.user, vv_id=id)  # type: ignore[arg-type]
        return FileResponse(
            build_results_zip(request=request, vv=vv),
            as_attachment=True,
            filename=results_filename(vv),
            content_type="application/zip",
        )
