"""A customer's members and invitations: every member reads them; owners invite, change
roles and remove members (accounts.roles)."""

from __future__ import annotations

from django.core.exceptions import ValidationError as DjangoValidationError
from django.db.models import QuerySet
from django.urls import reverse
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import extend_schema, extend_schema_view
from rest_framework import mixins, serializers, status, viewsets
from rest_framework.exceptions import NotFound, PermissionDenied
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.models import ROLE_CHOICES, Invite, User
from accounts.roles import OWNER, VIEWER
from accounts.selectors import (
    InviteNotFound,
    MemberNotFound,
    invite_get_for_user,
    invite_list_for_user,
    member_get_for_user,
    member_list_for_user,
)
from accounts.services import invite_create, invite_withdraw, member_remove, member_set_role
from cpcc_site.api import DetailSerializer, object_id, refusal

OWNERS_CHANGE = {"GET": VIEWER, "HEAD": VIEWER, "OPTIONS": VIEWER}


class _Owners:
    """Members read; owners change (MemberRole). Staff have no customer: nothing here."""

    role_needed = {
        m: OWNERS_CHANGE.get(m, OWNER)
        for m in ("GET", "HEAD", "OPTIONS", "POST", "PATCH", "PUT", "DELETE")
    }
    # Staff have no customer, so no members: whatever they send finds nothing.
    staff_write_perms = ()

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, DjangoValidationError):
            exc = refusal(exc)
        return super().handle_exception(exc)  # type: ignore[misc, no-any-return]


class MemberOutSerializer(serializers.ModelSerializer):
    class Meta:
        model = User
        fields = ["id", "username", "email", "role", "date_joined", "last_login"]


class MemberRoleSerializer(serializers.Serializer):
    role = serializers.ChoiceField(choices=ROLE_CHOICES)


class InviteInSerializer(serializers.Serializer):
    email = serializers.EmailField(max_length=254, help_text="Where the invitation is sent.")
    role = serializers.ChoiceField(choices=ROLE_CHOICES, help_text="Their role once in.")


class InviteOutSerializer(serializers.ModelSerializer):
    invited_by = serializers.SlugRelatedField(slug_field="username", read_only=True)
    open = serializers.BooleanField(read_only=True, help_text="False once it expired.")

    class Meta:
        model = Invite
        fields = ["id", "email", "role", "invited_by", "created", "expires", "open"]


@extend_schema_view(
    list=extend_schema(summary="Your customer's members"),
    retrieve=extend_schema(
        summary="One member", responses={200: MemberOutSerializer, 404: DetailSerializer}
    ),
    partial_update=extend_schema(
        summary="Change a member's role (owners)",
        request=MemberRoleSerializer,
        responses={200: MemberOutSerializer, 400: OpenApiTypes.OBJECT, 403: DetailSerializer},
    ),
    destroy=extend_schema(
        summary="Remove a member (owners): their tokens die with them",
        responses={204: None, 400: OpenApiTypes.OBJECT, 403: DetailSerializer},
    ),
)
class MemberViewSet(
    _Owners,
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """The people of your customer, each with a role: owner (everything, and the members),
    developer (submit, edit and cancel VVs, webhooks) or viewer (read only)."""

    serializer_class = MemberOutSerializer
    http_method_names = ["get", "patch", "delete", "head", "options"]
    noun = "member"

    def get_queryset(self) -> QuerySet[User]:
        if getattr(self, "swagger_fake_view", False):
            return User.objects.none()
        return member_list_for_user(user=self.request.user)  # type: ignore[arg-type]

    def get_object(self) -> User:
        try:
            return member_get_for_user(
                user=self.request.user,  # type: ignore[arg-type]
                member_id=object_id(self.kwargs["pk"]),
            )
        except (ValueError, MemberNotFound):
            raise NotFound(
                "No member with this id in your customer (GET /api/v1/members/ lists them)."
            ) from None

    def partial_update(self, request: Request, pk: str) -> Response:
        given = MemberRoleSerializer(data=request.data, partial=True)
        given.is_valid(raise_exception=True)
        member = self.get_object()
        if "role" in given.validated_data:
            member = member_set_role(member=member, role=given.validated_data["role"])
        return Response(MemberOutSerializer(member).data)

    def destroy(self, request: Request, pk: str) -> Response:
        member_remove(member=self.get_object())
        return Response(status=status.HTTP_204_NO_CONTENT)


@extend_schema_view(
    list=extend_schema(summary="Your customer's invitations not accepted yet"),
    retrieve=extend_schema(
        summary="One invitation", responses={200: InviteOutSerializer, 404: DetailSerializer}
    ),
    create=extend_schema(
        summary="Invite someone by e-mail (owners): a signed link, used once, that expires",
        request=InviteInSerializer,
        responses={201: InviteOutSerializer, 400: OpenApiTypes.OBJECT, 403: DetailSerializer},
    ),
    destroy=extend_schema(
        summary="Withdraw an invitation (owners): its link no longer works",
        responses={204: None, 403: DetailSerializer, 404: DetailSerializer},
    ),
)
class InviteViewSet(
    _Owners,
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """Invitations to join your customer: the link in the e-mail expires after
    CPCC_INVITE_DAYS and works once."""

    serializer_class = InviteOutSerializer
    http_method_names = ["get", "post", "delete", "head", "options"]
    noun = "invitation"

    def get_queryset(self) -> QuerySet[Invite]:
        if getattr(self, "swagger_fake_view", False):
            return Invite.objects.none()
        return invite_list_for_user(user=self.request.user).select_related("invited_by")  # type: ignore[arg-type]

    def get_object(self) -> Invite:
        try:
            return invite_get_for_user(
                user=self.request.user,  # type: ignore[arg-type]
                invite_id=object_id(self.kwargs["pk"]),
            )
        except (ValueError, InviteNotFound):
            raise NotFound(
                "No open invitation with this id (GET /api/v1/invites/ lists them)."
            ) from None

    def create(self, request: Request) -> Response:
        given = InviteInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        user = request.user
        if user.customer is None:  # type: ignore[union-attr]
            raise PermissionDenied("Only a customer's owners invite members.")
        invite = invite_create(
            customer=user.customer,  # type: ignore[union-attr]
            email=given.validated_data["email"],
            role=given.validated_data["role"],
            invited_by=user,  # type: ignore[arg-type]
            link=lambda signed: request.build_absolute_uri(
                reverse("account-invite", args=[signed])
            ),
        )
        return Response(InviteOutSerializer(invite).data, status=status.HTTP_201_CREATED)

    def destroy(self, request: Request, pk: str) -> Response:
        invite_withdraw(invite=self.get_object())
        return Response(status=status.HTTP_204_NO_CONTENT)
