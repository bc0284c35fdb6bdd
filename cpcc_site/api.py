"""REST API plumbing shared by the apps' ``api`` packages: the staff permission, the 409 error,
the JSON error shape for the schema, and content negotiation for endpoints that answer with a
file."""

from __future__ import annotations

from typing import Any

from rest_framework import serializers, status
from rest_framework.exceptions import APIException, NotAcceptable
from rest_framework.negotiation import DefaultContentNegotiation
from rest_framework.permissions import IsAdminUser
from rest_framework.renderers import BaseRenderer
from rest_framework.request import Request


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
