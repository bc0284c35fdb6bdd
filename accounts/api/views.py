"""The customer endpoints of the REST API (staff only): customers and their quotas."""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from django.db.models import QuerySet
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiResponse, extend_schema, extend_schema_view
from rest_framework import mixins, status, viewsets
from rest_framework.exceptions import NotFound
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.api.serializers import CustomerInSerializer, CustomerOutSerializer
from accounts.models import Customer
from accounts.selectors import customer_list
from cpcc_site.api import Conflict, DetailSerializer, IsStaff, object_id, refusal
from missions.selectors import with_active_vv_count
from vvm_worker.platform import platform_vvm
from vvm_worker.services import CustomerBusy, customer_create, customer_delete, customer_update

STAFF_ERRORS = {403: DetailSerializer, 404: DetailSerializer}
BAD_INPUT = {
    400: OpenApiResponse(
        OpenApiTypes.OBJECT,
        description="A value is malformed, or names a sensor the catalog does not hold (a rule "
        "that depends on what is stored). The body names the field.",
    )
}


@extend_schema_view(
    retrieve=extend_schema(responses={200: CustomerOutSerializer, **STAFF_ERRORS}),
    create=extend_schema(
        request=CustomerInSerializer,
        responses={
            201: CustomerOutSerializer,
            **BAD_INPUT,
            409: DetailSerializer,
            403: DetailSerializer,
        },
    ),
    update=extend_schema(
        request=CustomerInSerializer,
        responses={200: CustomerOutSerializer, **BAD_INPUT, 409: DetailSerializer, **STAFF_ERRORS},
    ),
    partial_update=extend_schema(
        request=CustomerInSerializer,
        responses={200: CustomerOutSerializer, **BAD_INPUT, 409: DetailSerializer, **STAFF_ERRORS},
    ),
    destroy=extend_schema(responses={204: None, 409: DetailSerializer, **STAFF_ERRORS}),
)
class CustomerViewSet(
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """The customers (staff only): who may use the platform, with which quotas and which SDC
    entries and VVM-API calls. A customer with VVs that have not ended cannot be deleted."""

    permission_classes = [IsAuthenticated, IsStaff]
    serializer_class = CustomerOutSerializer

    def get_queryset(self) -> QuerySet[Customer]:
        return with_active_vv_count(customer_list(), name="vvs_active")

    def get_object(self) -> Customer:
        try:
            return self.get_queryset().get(pk=object_id(self.kwargs["pk"]))
        except (ValueError, Customer.DoesNotExist):
            raise NotFound(f"No customer with id {self.kwargs['pk']!r}.") from None

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, DjangoValidationError):
            exc = refusal(exc)
        elif isinstance(exc, CustomerBusy):
            exc = Conflict(
                f"{exc.customer.name} has {exc.count} VV(s) that have not ended; "
                "cancel them (POST /api/v1/vvs/{id}/cancel/) or wait until they end."
            )
        return super().handle_exception(exc)

    def _shown(self, customer: Customer, code: int = status.HTTP_200_OK) -> Response:
        fresh = self.get_queryset().get(pk=customer.pk)
        return Response(self.get_serializer(fresh).data, status=code)

    def create(self, request: Request) -> Response:
        given = CustomerInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        customer = customer_create(config=given.config(), allowed_sensors=given.sensor_names())
        return self._shown(customer, status.HTTP_201_CREATED)

    def update(self, request: Request, pk: str, partial: bool = False, **kwargs: Any) -> Response:
        given = CustomerInSerializer(data=request.data, partial=partial)
        given.is_valid(raise_exception=True)
        customer = customer_update(
            customer=self.get_object(),
            config=given.config(),
            allowed_sensors=given.sensor_names(),
            vvm=platform_vvm(),
        )
        return self._shown(customer)

    def partial_update(self, request: Request, pk: str) -> Response:
        return self.update(request, pk, partial=True)

    def destroy(self, request: Request, pk: str) -> Response:
        customer_delete(customer=self.get_object())
        return Response(status=status.HTTP_204_NO_CONTENT)
