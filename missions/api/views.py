"""The VV endpoints of the REST API (DESIGN.md section 6), always scoped to the caller."""

from __future__ import annotations

from django.db.models import QuerySet
from drf_spectacular.utils import OpenApiParameter, extend_schema, extend_schema_view
from rest_framework import mixins, status, viewsets
from rest_framework.exceptions import PermissionDenied
from rest_framework.request import Request
from rest_framework.response import Response

from missions.api.serializers import VVCreateSerializer, VVSerializer
from missions.models import VirtualVehicle, VVStatus
from missions.selectors import vv_list_for_user
from missions.services import NotACustomer, vv_create_for_user


@extend_schema_view(
    list=extend_schema(
        parameters=[
            OpenApiParameter("status", enum=VVStatus.values, description="only VVs in this state")
        ]
    )
)
class VirtualVehicleViewSet(
    mixins.ListModelMixin, mixins.RetrieveModelMixin, viewsets.GenericViewSet
):
    """Your virtual vehicles: submit a program, list them, look at one.

    Another customer's VV answers 404, like one that does not exist.
    """

    serializer_class = VVSerializer
    lookup_value_regex = "[0-9a-fA-F-]{36}"

    def get_queryset(self) -> QuerySet[VirtualVehicle]:
        vvs = vv_list_for_user(user=self.request.user).order_by("-created")  # type: ignore[arg-type]
        wanted = self.request.query_params.get("status")
        return vvs.filter(status=wanted) if wanted else vvs

    @extend_schema(request=VVCreateSerializer, responses={201: VVSerializer})
    def create(self, request: Request) -> Response:
        given = VVCreateSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        try:
            vv, problem = vv_create_for_user(user=request.user, **given.validated_data)  # type: ignore[arg-type]
        except NotACustomer:
            raise PermissionDenied("Only a customer's users can submit VVs.") from None
        if problem is not None:
            error = {"message": problem.message, "line": problem.line, "column": problem.column}
            return Response(
                {"program": [str(problem)], "error": error}, status=status.HTTP_400_BAD_REQUEST
            )
        return Response(self.get_serializer(vv).data, status=status.HTTP_201_CREATED)
