"""REST API plumbing shared by the apps' ``api`` packages: the staff permission, the 409 and 429
errors, the JSON error shape for the schema, the JSON parser, content negotiation for endpoints
that answer with a file, and authentication that the audit log sees. (The throttles:
cpcc_site/throttling.py.)"""

from __future__ import annotations

from collections.abc import Mapping
from typing import IO, Any

from auditlog.context import auditlog_value
from django.core.exceptions import ValidationError as DjangoValidationError
from drf_spectacular.authentication import SessionScheme
from drf_spectacular.extensions import OpenApiSerializerFieldExtension
from rest_framework import serializers, status
from rest_framework.authentication import SessionAuthentication, TokenAuthentication
from rest_framework.exceptions import APIException, NotAcceptable, ParseError, ValidationError
from rest_framework.negotiation import DefaultContentNegotiation
from rest_framework.pagination import PageNumberPagination
from rest_framework.parsers import JSONParser
from rest_framework.permissions import IsAdminUser
from rest_framework.renderers import BaseRenderer
from rest_framework.request import Request
from rest_framework.serializers import as_serializer_error

from cpcc_site.json_depth import too_deep, too_deep_message


class IsStaff(IsAdminUser):
    """Platform staff only (DRF's is_staff check); everyone else gets 403 saying so."""

    message = (
        "Only platform staff may manage the fleet and the customers; "
        "ask an administrator if you need to."
    )


class Conflict(APIException):
    """409: the request is valid but the current state does not allow it."""

    status_code = status.HTTP_409_CONFLICT
    default_detail = "The request conflicts with the current state."
    default_code = "conflict"


# Django's codes for a value another record holds already.
_TAKEN = {"unique", "unique_together"}


def refusal(
    exc: DjangoValidationError, field_names: Mapping[str, str] | None = None
) -> APIException:
    """A service's ValidationError as the API's answer, its fields named as the API names them
    (``field_names``): 409 when every problem is a value another record holds already (a name
    in use: a matter of what is stored, not of the request's form), 400 otherwise."""
    errors: dict[str, list[Any]] = {}
    for field, messages in as_serializer_error(exc).items():
        errors.setdefault((field_names or {}).get(field, field), []).extend(messages)
    problems = (
        [error for field in exc.error_dict.values() for error in field]
        if hasattr(exc, "error_dict")
        else exc.error_list
    )
    if problems and all(problem.code in _TAKEN for problem in problems):
        return Conflict(error_body(errors))
    return ValidationError(errors)


class QuotaReached(APIException):
    """429: one of the customer's quotas allows no more of this now (not a request rate: waiting
    alone does not help, the message says what does)."""

    status_code = status.HTTP_429_TOO_MANY_REQUESTS
    default_detail = "A quota of your account allows no more of this now."
    default_code = "quota_reached"


class DepthLimitedJSONParser(JSONParser):
    """DRF's JSON parser (DEFAULT_PARSER_CLASSES), refusing with 400 a body nested more than
    MAX_VALUE_DEPTH levels deep (cpcc_site/json_depth.py); DRF's own lets the parser's
    RecursionError through, a server error."""

    def parse(
        self,
        stream: IO[Any],
        media_type: str | None = None,
        parser_context: Mapping[str, Any] | None = None,
    ) -> Any:
        try:
            value = super().parse(stream, media_type, parser_context)
        except RecursionError:
            raise ParseError(too_deep_message("The request body")) from None
        if too_deep(value):
            raise ParseError(too_deep_message("The request body"))
        return value


class DetailSerializer(serializers.Serializer):
    """The JSON body of an error: what went wrong and, where it helps, what to do."""

    detail = serializers.CharField()


class FileOrJSONNegotiation(DefaultContentNegotiation):
    """For endpoints that answer with a file (an image, a zip): an ``Accept`` header asking for
    the file's type must not be refused with 406 before the view runs. The file bypasses the
    renderers; anything else (an error, ``?format=json``) is rendered as usual, falling back
    to the first renderer (JSON)."""

    def select_renderer(
        self, request: Request, renderers: list[BaseRenderer], format_suffix: str | None = None
    ) -> tuple[BaseRenderer, Any]:
        try:
            return super().select_renderer(request, renderers, format_suffix)  # type: ignore[no-any-return]
        except NotAcceptable:
            return renderers[0], renderers[0].media_type


def object_id(raw: object) -> int:
    """A database id from a URL: a positive integer that fits the id column (64 bits).
    Raises ValueError otherwise, which views answer with 404."""
    value = int(str(raw))
    if not 0 < value < 2**63:
        raise ValueError(f"{raw!r} is not an id")
    return value


def _note_actor(user: Any) -> None:
    """Tell the audit log who acts in this request (its middleware ran before DRF knew)."""
    try:
        context = auditlog_value.get()
    except LookupError:
        return
    context["actor"] = user


class _Audited:
    """An authentication class whose user the audit log records as the actor."""

    def authenticate(self, request: Request) -> tuple[Any, Any] | None:
        result = super().authenticate(request)  # type: ignore[misc]
        if result is not None:
            _note_actor(result[0])
        return result  # type: ignore[no-any-return]


class AuditedTokenAuthentication(_Audited, TokenAuthentication):
    """Token authentication, audited."""


class AuditedSessionAuthentication(_Audited, SessionAuthentication):
    """Session authentication (the browsable API, the pages' scripts), audited likewise."""


_ERROR = {"application/json": {"schema": {"$ref": "#/components/schemas/Detail"}}}
_ERRORS = {
    "400": "The request is malformed or a value is invalid: the body says which and why.",
    "401": "No credentials, or a token that is not valid (send 'Authorization: Token ...').",
    "403": "Your account may not do this.",
    "404": "No such object (another customer's answers the same), or no such page.",
    "413": "The request body is larger than the platform accepts (CPCC_MAX_REQUEST_BYTES).",
    "415": "The body's content type is not one the endpoint reads (send JSON).",
    "429": "Too many requests from your token or address (wait as Retry-After says), or a "
    "quota of your account reached (the body says which and what to do).",
}


def nullable_as_json_schema(result: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    """drf-spectacular postprocessing hook: OpenAPI 3.1 says "may be null" as JSON Schema does
    (``"type": ["string", "null"]``); schemas written by hand in OpenAPI 3.0's words
    (``"nullable": true``) are said so too."""

    def visit(node: Any) -> Any:
        if isinstance(node, list):
            return [visit(item) for item in node]
        if not isinstance(node, dict):
            return node
        node = {key: visit(value) for key, value in node.items()}
        if node.pop("nullable", False):
            kind = node.get("type")
            if isinstance(kind, str):
                node["type"] = [kind, "null"]
            elif isinstance(kind, list):
                node["type"] = [*kind, "null"] if "null" not in kind else kind
            else:  # a $ref or a composition: it, or null
                node = {"oneOf": [node, {"type": "null"}]}
        return node

    return visit(result)  # type: ignore[no-any-return]


def add_error_responses(result: dict[str, Any], **kwargs: Any) -> dict[str, Any]:
    """drf-spectacular postprocessing hook: every API operation documents the errors any
    request may get (401, 403, 429; 400 and 404 where it takes parameters, 400, 413 and 415
    where it takes a body), each a JSON ``{"detail": ...}`` body."""
    for path, operations in result.get("paths", {}).items():
        if not path.startswith("/api/v"):
            continue
        for operation in operations.values():
            if not isinstance(operation, dict) or "responses" not in operation:
                continue
            codes = ["401", "403", "429"]
            if operation.get("parameters") or "{" in path:
                codes += ["400", "404"]
            if "requestBody" in operation:
                codes += ["400", "413", "415"]
            for code in codes:
                operation["responses"].setdefault(
                    code, {"description": _ERRORS[code], "content": _ERROR}
                )
    return result


class AuditedSessionScheme(SessionScheme):
    """The session cookie in the schema, for the audited session authentication."""

    target_class = "cpcc_site.api.AuditedSessionAuthentication"


class StrictPageNumberPagination(PageNumberPagination):
    """Pages of PAGE_SIZE; a ``page`` that is not a positive whole number is a 400 that says so
    (DRF's own treats an empty one as page 1)."""

    def get_page_number(self, request: Any, paginator: Any) -> Any:
        raw = request.query_params.get(self.page_query_param)
        valid = raw is None or raw in self.last_page_strings
        if not valid and not (raw.isascii() and raw.isdigit() and int(raw) > 0):
            raise ValidationError({"page": [f"{raw!r} is not a page number (1, 2, ...)."]})
        return super().get_page_number(request, paginator)

    def get_schema_operation_parameters(self, view: Any) -> list[dict[str, Any]]:
        parameters = super().get_schema_operation_parameters(view)
        for parameter in parameters:
            if parameter["name"] == self.page_query_param:
                parameter["schema"] = {"type": "integer", "minimum": 1}
        return parameters


def exception_handler(exc: Exception, context: dict[str, Any]) -> Any:
    """DRF's error responses, each with a ``detail`` sentence a person can act on: field
    errors (``{"name": ["..."]}``) keep their fields and get a ``detail`` naming the first."""
    # Imported here: rest_framework.views reads the authentication classes of this module.
    from rest_framework.views import exception_handler as drf_exception_handler

    response = drf_exception_handler(exc, context)
    if response is None:
        return None
    data = response.data
    if isinstance(data, list):
        response.data = {"detail": " ".join(str(item) for item in data), "errors": data}
    elif isinstance(data, dict) and "detail" not in data:
        response.data = error_body(data)
    return response


def error_body(errors: dict[str, Any]) -> dict[str, Any]:
    """Field errors (``{"name": ["..."]}``) as an answer's body: with a ``detail`` naming the
    first problem."""
    return {"detail": _first_problem(errors), **errors}


def _first_problem(errors: dict[str, Any]) -> str:
    field, messages = next(iter(errors.items()))
    while isinstance(messages, dict) and messages:  # a nested field: its path, dotted
        key, messages = next(iter(messages.items()))
        field = f"{field}.{key}"
    first = messages[0] if isinstance(messages, list) and messages else messages
    more = len(errors) - 1
    return f"{field}: {first}" + (f" (and {more} more field(s))" if more > 0 else "")


# Request bodies are JSON (DEFAULT_PARSER_CLASSES): a value of the wrong JSON type is refused,
# not converted (DRF's own fields turn 0 into "0" and "1.5" into 1.5).


def _refuse_type(field: serializers.Field, data: Any, *types: type) -> None:
    if (isinstance(data, bool) and bool not in types) or not isinstance(data, types):
        raise ValidationError(f"Expected {field.type_name}, got {type(data).__name__}: {data!r}.")  # type: ignore[attr-defined]


class StrictCharField(serializers.CharField):
    """A string, and only a string."""

    type_name = "a string"

    def to_internal_value(self, data: Any) -> str:
        _refuse_type(self, data, str)
        return super().to_internal_value(data)  # type: ignore[no-any-return]


class StrictCharFieldSchema(OpenApiSerializerFieldExtension):
    """What the schema says of a strict string: one that may not be blank is not empty and,
    unless it keeps its white space, holds something besides (DRF trims it and refuses what
    is left empty)."""

    target_class = "cpcc_site.api.StrictCharField"

    def map_serializer_field(self, auto_schema: Any, direction: str) -> dict[str, Any]:
        schema: dict[str, Any] = auto_schema._map_serializer_field(
            self.target, direction, bypass_extensions=True
        )
        if direction == "request" and not self.target.allow_blank:
            schema.setdefault("minLength", 1)
            if self.target.trim_whitespace:  # a program keeps its white space
                schema.setdefault("pattern", NOT_BLANK)
        return schema


# Something besides white space, as a schema's (ECMA-262) pattern says it.
NOT_BLANK = r"[^\s\x1c-\x1f\x85]"


class StrictFloatField(serializers.FloatField):
    """A JSON number (not a string of digits, not a boolean)."""

    type_name = "a number"

    def to_internal_value(self, data: Any) -> float:
        _refuse_type(self, data, int, float)
        return super().to_internal_value(data)  # type: ignore[no-any-return]


class StrictIntegerField(serializers.IntegerField):
    """A JSON whole number."""

    type_name = "a whole number"

    def to_internal_value(self, data: Any) -> int:
        _refuse_type(self, data, int)
        return super().to_internal_value(data)  # type: ignore[no-any-return]


class StrictSlugField(serializers.SlugField):
    """A slug given as a string (DRF's own turns 0 into "0")."""

    type_name = "a string"

    def to_internal_value(self, data: Any) -> str:
        _refuse_type(self, data, str)
        return super().to_internal_value(data)  # type: ignore[no-any-return]


class StrictBooleanField(serializers.BooleanField):
    """true or false."""

    type_name = "true or false"

    def to_internal_value(self, data: Any) -> bool:
        _refuse_type(self, data, bool)
        return super().to_internal_value(data)  # type: ignore[no-any-return]
