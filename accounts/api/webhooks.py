"""``/api/v1/webhooks/``: a customer's webhooks and their delivery logs (DESIGN.md section 9).

Made with ``{"url", "events"}``; the answer to that POST holds the ``secret`` that signs every
delivery (``X-CPCC-Signature: sha256=<hex HMAC-SHA256 of the raw body>``), shown this once.
A URL the customer already hooks answers 409; another customer's webhook 404.
"""

from __future__ import annotations

from typing import Any

from django.conf import settings
from django.core.exceptions import ValidationError as DjangoValidationError
from django.core.validators import RegexValidator
from django.db.models import QuerySet
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema, extend_schema_field, extend_schema_view
from rest_framework import mixins, serializers, status, viewsets
from rest_framework.decorators import action
from rest_framework.exceptions import NotFound, PermissionDenied
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.models import NotifyEvent, Webhook, WebhookDelivery
from accounts.selectors import (
    WebhookNotFound,
    webhook_deliveries_for_user,
    webhook_get_for_user,
    webhook_list_for_user,
)
from accounts.services import webhook_create, webhook_delete
from cpcc_site.api import DetailSerializer, StrictCharField, object_id, refusal

# An http(s) URL, which the schema says too (the service checks more: that its host resolves,
# and to which addresses).
HTTP_URL = r"^https?://[^\s/?#@]+(?:[/?#]\S*)?$"


@extend_schema_field(
    {"type": "string", "format": "uri", "pattern": HTTP_URL, "minLength": 8, "maxLength": 2000}
)
class WebhookURLField(StrictCharField):
    """A webhook's URL: a string that starts with http:// or https:// and a host."""

    def __init__(self, **kwargs: Any) -> None:
        message = "Give an http:// or https:// URL, e.g. https://example.com/cpcc-hook."
        super().__init__(
            max_length=2000, validators=[RegexValidator(HTTP_URL, message=message)], **kwargs
        )


NO_SUCH_WEBHOOK = "No webhook with this id among yours (GET /api/v1/webhooks/ lists them)."
NOT_A_CUSTOMER = "Webhooks belong to a customer: log in as one of its users."
EVENTS_HELP = (
    "vv.finished (a VV finished), vv.failed (a VV failed or was killed), task.done (one of "
    "its tasks was done)."
)


class WebhookInSerializer(serializers.Serializer):
    """A new webhook: where to POST, and on which events."""

    url = WebhookURLField(
        help_text="http:// or https://; its host must resolve to addresses on the public "
        "internet (a loopback, private or link-local one is refused with 400 unless the "
        "platform allows them).",
    )
    events = serializers.ListField(
        child=serializers.ChoiceField(choices=NotifyEvent.choices),
        min_length=1,
        max_length=len(NotifyEvent.values),
        help_text=EVENTS_HELP,
        error_messages={
            "min_length": f"Choose at least one event: {', '.join(NotifyEvent.values)}.",
            "max_length": f"Each event once at most: {', '.join(NotifyEvent.values)}.",
        },
    )


class WebhookOutSerializer(serializers.ModelSerializer):
    """A webhook as its customer sees it: never its secret."""

    events = serializers.ListField(
        child=serializers.ChoiceField(choices=NotifyEvent.choices), help_text=EVENTS_HELP
    )

    class Meta:
        model = Webhook
        fields = ["id", "url", "events", "created"]


class WebhookCreatedSerializer(WebhookOutSerializer):
    """A webhook just made, with the secret that signs its deliveries: shown this once."""

    secret = StrictCharField(
        help_text="Verify each delivery: X-CPCC-Signature is 'sha256=' and the hex "
        "HMAC-SHA256 of the raw body with this secret. Shown this once."
    )

    class Meta(WebhookOutSerializer.Meta):
        fields = [*WebhookOutSerializer.Meta.fields, "secret"]


class WebhookDeliveryOutSerializer(serializers.ModelSerializer):
    """One attempt to deliver an event: what the receiver answered, or why it did not."""

    vv = serializers.UUIDField(source="vv_id", help_text="The VV's id (the body's id).")
    task = serializers.IntegerField(
        source="task_id", allow_null=True, help_text="The task's id, for task.done."
    )
    status_code = serializers.IntegerField(
        allow_null=True, help_text="What the receiver answered; null: no answer (see error)."
    )
    error = StrictCharField(help_text="Why the attempt failed; empty when it was delivered.")
    ok = serializers.BooleanField(help_text="Delivered: the receiver answered 2xx.")

    class Meta:
        model = WebhookDelivery
        fields = [
            "id",
            "delivery",
            "event",
            "vv",
            "task",
            "attempt",
            "status_code",
            "error",
            "ok",
            "duration_ms",
            "at",
        ]


@extend_schema_view(
    list=extend_schema(summary="Your webhooks"),
    retrieve=extend_schema(
        summary="One of your webhooks", responses={200: WebhookOutSerializer, 404: DetailSerializer}
    ),
    create=extend_schema(
        summary="Add a webhook (its secret is in this answer only)",
        request=WebhookInSerializer,
        responses={
            201: WebhookCreatedSerializer,
            400: OpenApiTypes.OBJECT,
            403: DetailSerializer,
            409: DetailSerializer,
        },
    ),
    destroy=extend_schema(
        summary="Remove a webhook and its delivery log",
        responses={204: None, 404: DetailSerializer},
    ),
)
class WebhookViewSet(
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """Your webhooks: a signed POST to your URL when one of your VVs finishes, fails or has a
    task done; each attempt (retried with back-off when your receiver does not answer 2xx) in
    the webhook's delivery log."""

    serializer_class = WebhookOutSerializer

    def get_queryset(self) -> QuerySet[Webhook]:
        if getattr(self, "swagger_fake_view", False):  # the schema: ids are the model's
            return Webhook.objects.none()
        return webhook_list_for_user(user=self.request.user)  # type: ignore[arg-type]

    def _webhook_id(self) -> int:
        try:
            return object_id(self.kwargs["pk"])
        except ValueError:
            raise NotFound(NO_SUCH_WEBHOOK) from None

    def get_object(self) -> Webhook:
        return webhook_get_for_user(user=self.request.user, webhook_id=self._webhook_id())  # type: ignore[arg-type]

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, WebhookNotFound):
            exc = NotFound(NO_SUCH_WEBHOOK)
        elif isinstance(exc, DjangoValidationError):
            exc = refusal(exc)  # 409 for a name or URL in use, 400 otherwise
        return super().handle_exception(exc)

    def create(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        customer = getattr(request.user, "customer", None)
        if customer is None:
            raise PermissionDenied(NOT_A_CUSTOMER)
        given = WebhookInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        webhook = webhook_create(
            customer=customer,
            url=given.validated_data["url"],
            events=given.validated_data["events"],
            allow_private=settings.CPCC_WEBHOOK_ALLOW_PRIVATE,
        )
        return Response(WebhookCreatedSerializer(webhook).data, status=status.HTTP_201_CREATED)

    def destroy(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        webhook_delete(webhook=self.get_object())
        return Response(status=status.HTTP_204_NO_CONTENT)

    @extend_schema(
        summary="The webhook's delivery log, newest first",
        responses={200: WebhookDeliveryOutSerializer(many=True), 404: DetailSerializer},
    )
    @action(detail=True, methods=["get"], serializer_class=WebhookDeliveryOutSerializer)
    def deliveries(self, request: Request, pk: str) -> Response:
        attempts = webhook_deliveries_for_user(user=request.user, webhook_id=self._webhook_id())  # type: ignore[arg-type]
        page = self.paginate_queryset(attempts)
        serializer = WebhookDeliveryOutSerializer(page, many=True)
        return self.get_paginated_response(serializer.data)
