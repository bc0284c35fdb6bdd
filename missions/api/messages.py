"""``/api/v1/vvs/{id}/messages/``: a VV's messages in and out (``VV.message.send`` between the
customer's VVs), and a message from the customer's own system to a VV that has not ended, which
its program takes with ``VV.message.receive`` (``from: null``).
"""

from __future__ import annotations

import json
import uuid
from typing import Any

from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema, extend_schema_field, extend_schema_view
from rest_framework import generics, serializers, status
from rest_framework.request import Request
from rest_framework.response import Response

from cpcc_site.api import Conflict, DetailSerializer, StrictCharField
from missions.api.serializers import platform_time
from missions.api.views import NOT_FOUND, VV_ID, VVErrorsMixin
from missions.models import Message
from missions.selectors import vv_messages_pages_for_user
from vvm_worker.platform import platform_vvm
from vvm_worker.services import VVAlreadyEnded
from vvm_worker.services.messages import MessageError, vv_message_send_for_user


class MessagePartySerializer(serializers.Serializer):
    """A VV at one end of a message: its id and name."""

    id = serializers.UUIDField(
        allow_null=True, help_text="The VV's id; null for a sender VV that no longer exists."
    )
    name = StrictCharField(help_text="The VV's name (a sender's: when it sent the message).")


class MessageOutSerializer(serializers.Serializer):
    """A message as the VV it went to or came from sees it."""

    id = serializers.IntegerField(help_text="The message's id: the order it was sent in.")
    direction = serializers.ChoiceField(
        choices=["in", "out"],
        help_text="in: sent to this VV (a message it sent itself is listed once, as in); "
        "out: sent by this VV to another.",
    )
    to = MessagePartySerializer(help_text="The VV it was sent to.")
    value = serializers.JSONField(help_text="The value sent: any JSON.")
    bytes = serializers.IntegerField(help_text="The value's size as JSON text, in UTF-8 bytes.")
    sent_at = serializers.DateTimeField()
    received_at = serializers.DateTimeField(
        allow_null=True, help_text="When the recipient took it (VV.message.receive); null: not yet."
    )

    def get_fields(self) -> dict[str, serializers.Field]:
        # ``from`` is a Python keyword: no attribute can declare it.
        declared = super().get_fields()
        sender = MessagePartySerializer(
            allow_null=True,
            help_text="The VV that sent it; null: sent over the API (POST to this endpoint).",
        )
        return {"id": declared.pop("id"), "direction": declared.pop("direction")} | {
            "from": sender,
            **declared,
        }

    def to_representation(self, instance: Message) -> dict[str, Any]:
        # Written out (as VVSerializer's): the page of a list holds up to 50 of them.
        message = instance
        recipient = message.recipient
        if message.sender_id is None and not message.sender_name:
            sender = None
        else:
            sender_id = None if message.sender_id is None else str(message.sender_id)
            sender = {"id": sender_id, "name": message.sender_name}
        return {
            "id": message.pk,
            "direction": message_direction(message, self.context["vv_id"]),
            "from": sender,
            "to": {"id": str(message.recipient_id), "name": recipient.name},
            "value": json.loads(message.value),
            "bytes": message.bytes,
            "sent_at": platform_time(recipient, message.sent_s),
            "received_at": platform_time(recipient, message.received_s),
        }


def message_direction(message: Message, vv_id: uuid.UUID) -> str:
    """``in`` for a message to the VV ``vv_id`` (one it sent itself too), ``out`` otherwise."""
    return "in" if message.recipient_id == vv_id else "out"


@extend_schema_field(OpenApiTypes.ANY)
class AnyJSONField(serializers.JSONField):
    """Any JSON value, null included: a field that must be given, whose null is a value like
    any other (DRF's ``allow_null`` would make the schema say "anything, or null", which
    OpenAPI 3.1 reads as refusing null, matched twice)."""

    def validate_empty_values(self, data: Any) -> tuple[bool, Any]:
        if data is None:
            return False, None
        return super().validate_empty_values(data)  # type: ignore[no-any-return]


class MessageInSerializer(serializers.Serializer):
    """A message from your own system to one of your VVs."""

    value = AnyJSONField(
        help_text="Any JSON value that VV.storage.store accepts; at most your max_message_bytes "
        "as JSON text (UTF-8).",
    )


@extend_schema_view(
    get=extend_schema(
        parameters=[VV_ID],
        responses={200: MessageOutSerializer(many=True), **NOT_FOUND},
        description="The VV's messages, in (sent to it) and out (sent by it), newest first.",
    ),
    post=extend_schema(
        parameters=[VV_ID],
        request=MessageInSerializer,
        responses={
            201: MessageOutSerializer,
            400: DetailSerializer,
            **NOT_FOUND,
            409: DetailSerializer,
        },
        description="Send `value` to the VV from your own system: its program takes it with "
        "`VV.message.receive`, after the messages sent to it before, as `{from: null, id: "
        "null, value, sentAt}`. 400 for a value the platform cannot keep or larger than your "
        "max_message_bytes (the body says which); 409 when the VV has ended.",
    ),
)
class VVMessagesView(VVErrorsMixin, generics.ListAPIView):  # type: ignore[type-arg]
    """The VV's messages in and out, and a message to it from your own system. Another
    customer's VV answers 404, like one that does not exist."""

    serializer_class = MessageOutSerializer

    def get_serializer_context(self) -> dict[str, Any]:
        # The URL's id, checked by the selector before any message is shown.
        return super().get_serializer_context() | {"vv_id": uuid.UUID(self.kwargs["id"])}

    def list(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        # The pages, each read with SQL written once.
        messages = vv_messages_pages_for_user(user=request.user, vv_id=self.kwargs["id"])  # type: ignore[arg-type]
        page = self.paginate_queryset(messages)  # type: ignore[arg-type]
        assert page is not None, "the API paginates every list"
        return self.get_paginated_response(self.get_serializer(page, many=True).data)

    def post(self, request: Request, id: str) -> Response:
        given = MessageInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        try:
            message = vv_message_send_for_user(
                user=request.user,  # type: ignore[arg-type]
                vv_id=id,
                value=given.validated_data["value"],
                vvm=platform_vvm(),
            )
        except VVAlreadyEnded as exc:
            raise Conflict(
                f"{exc.vv.name!r} has already ended ({exc.vv.status}): it takes no more messages."
            ) from None
        except MessageError as exc:
            return Response(
                {"detail": str(exc), "value": [str(exc)]}, status=status.HTTP_400_BAD_REQUEST
            )
        return Response(self.get_serializer(message).data, status=status.HTTP_201_CREATED)
