"""``/api/v1/tokens/``: a user's named API tokens. List them (with when each was last used),
make one (its key is in that answer only; a name the user already gave a token: 409) and revoke
one. Another user's token answers 404.

A token is made by a user who logged in with a password (a session: the Account page, the
browsable API), never with a token: a token that leaked cannot make others that would outlive
its revocation. Nor can it revoke its user's other tokens (and lock every integration of the
user out): a token may revoke itself; other tokens are revoked with a session.
"""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from django.db.models import QuerySet
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema, extend_schema_view
from rest_framework import mixins, serializers, status, viewsets
from rest_framework.exceptions import NotFound, PermissionDenied
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.models import ROLE_CHOICES, ApiToken
from accounts.roles import VIEWER
from accounts.selectors import ApiTokenNotFound, api_token_get_for_user, api_token_list_for_user
from accounts.services import api_token_create, api_token_revoke
from cpcc_site.api import DetailSerializer, StrictCharField, object_id, refusal

NO_SUCH_TOKEN = "No API token with this id among yours (GET /api/v1/tokens/ lists them)."
TOKENS_NEED_A_PASSWORD = (
    "An API token cannot make another: make tokens on the platform's Account page (API "
    "tokens), logged in with your password."
)
ONLY_ITSELF = (
    "An API token can revoke only itself: revoke your other tokens on the platform's Account "
    "page (API tokens), logged in with your password."
)


class ApiTokenInSerializer(serializers.Serializer):
    """A new token: what to call it."""

    name = StrictCharField(
        max_length=100, help_text='Where it is used, e.g. "laptop" or "CI"; yours are unique.'
    )
    role = serializers.ChoiceField(
        choices=ROLE_CHOICES,
        required=False,
        help_text="What it may do, at most what you may (viewer: read only, e.g. for a "
        "dashboard); left out: your role, as that changes.",
    )


class ApiTokenOutSerializer(serializers.ModelSerializer):
    """A token as its owner sees it: never its key."""

    prefix = StrictCharField(
        source="token_key", help_text="The key's first characters, which identify it."
    )
    last_used = serializers.DateTimeField(
        allow_null=True,
        help_text="When a request last came with it (kept to the minute); null: never.",
    )

    role = serializers.CharField(
        read_only=True,
        help_text="The role it acts with at most; empty: its user's role.",
    )

    class Meta:
        model = ApiToken
        fields = ["id", "name", "prefix", "role", "created", "last_used"]


class ApiTokenCreatedSerializer(ApiTokenOutSerializer):
    """A token just made, with its key: shown in this answer only."""

    key = StrictCharField(
        help_text="The token: send it as 'Authorization: Token KEY'. Shown this once; the "
        "platform keeps only a digest of it."
    )

    class Meta(ApiTokenOutSerializer.Meta):
        fields = [*ApiTokenOutSerializer.Meta.fields, "key"]


@extend_schema_view(
    list=extend_schema(summary="Your API tokens, newest first"),
    retrieve=extend_schema(
        summary="One of your API tokens",
        responses={200: ApiTokenOutSerializer, 404: DetailSerializer},
    ),
    create=extend_schema(
        summary="Make an API token (its key is in this answer only)",
        request=ApiTokenInSerializer,
        responses={
            201: ApiTokenCreatedSerializer,
            400: OpenApiTypes.OBJECT,
            403: DetailSerializer,
            409: DetailSerializer,
        },
    ),
    destroy=extend_schema(
        summary="Revoke an API token: refused from now on",
        description="With a token, only that token itself; any of yours with a session.",
        responses={204: None, 403: DetailSerializer, 404: DetailSerializer},
    ),
)
class ApiTokenViewSet(
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """Your named API tokens: make one for each place you use the API (a laptop, CI), see when
    each was last used, and revoke one you no longer use or that may have leaked."""

    serializer_class = ApiTokenOutSerializer
    # A member's own tokens, whatever their role; staff theirs.
    role_needed = VIEWER
    staff_write_perms = ()

    def get_queryset(self) -> QuerySet[ApiToken]:
        if getattr(self, "swagger_fake_view", False):  # the schema: ids are the model's
            return ApiToken.objects.none()
        return api_token_list_for_user(user=self.request.user)  # type: ignore[arg-type]

    def get_object(self) -> ApiToken:
        try:
            token_id = object_id(self.kwargs["pk"])
            return api_token_get_for_user(user=self.request.user, token_id=token_id)  # type: ignore[arg-type]
        except (ValueError, ApiTokenNotFound):
            raise NotFound(NO_SUCH_TOKEN) from None

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, DjangoValidationError):
            exc = refusal(exc)  # 409 for a name or URL in use, 400 otherwise
        return super().handle_exception(exc)

    def create(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        if request.auth is not None:
            raise PermissionDenied(TOKENS_NEED_A_PASSWORD)
        given = ApiTokenInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        token, key = api_token_create(
            user=request.user,  # type: ignore[arg-type]
            name=given.validated_data["name"],
            role=given.validated_data.get("role", ""),
        )
        token.key = key  # type: ignore[attr-defined]  # this answer's only: never stored
        return Response(ApiTokenCreatedSerializer(token).data, status=status.HTTP_201_CREATED)

    def destroy(self, request: Request, *args: Any, **kwargs: Any) -> Response:
        token = self.get_object()
        if request.auth is not None and not (
            isinstance(request.auth, ApiToken) and request.auth.pk == token.pk
        ):
            raise PermissionDenied(ONLY_ITSELF)
        api_token_revoke(token=token)
        return Response(status=status.HTTP_204_NO_CONTENT)
