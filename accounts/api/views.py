"""The customer endpoints of the REST API (staff only): customers and their quotas, and the
service classes they may be in."""

from __future__ import annotations

from typing import Any

from django.core.exceptions import ValidationError as DjangoValidationError
from django.db.models import Count, QuerySet
from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiResponse, extend_schema, extend_schema_view
from rest_framework import mixins, status, viewsets
from rest_framework.exceptions import NotFound
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response

from accounts.api.serializers import (
    CustomerInSerializer,
    CustomerOutSerializer,
    ServiceClassInSerializer,
    ServiceClassListSerializer,
)
from accounts.models import Customer, ServiceClass
from accounts.selectors import customer_list
from cpcc_site.api import Conflict, DetailSerializer, object_id, refusal
from cpcc_site.permissions import StaffPermission
from missions.selectors import with_active_vv_count
from vvm_worker.platform import platform_vvm
from vvm_worker.services import CustomerBusy, customer_create, customer_delete, customer_update
from vvm_worker.services.customers import service_class_save

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

    permission_classes = [IsAuthenticated, StaffPermission]
    serializer_class = CustomerOutSerializer
    staff_model = Customer

    def get_queryset(self) -> QuerySet[Customer]:
        return with_active_vv_count(
            customer_list().select_related("service_class"), name="vvs_active"
        )

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


@extend_schema_view(
    list=extend_schema(
        responses={200: ServiceClassListSerializer(many=True), 403: DetailSerializer}
    ),
    retrieve=extend_schema(responses={200: ServiceClassListSerializer, **STAFF_ERRORS}),
    create=extend_schema(
        request=ServiceClassInSerializer,
        responses={
            200: ServiceClassListSerializer,
            201: ServiceClassListSerializer,
            **BAD_INPUT,
            403: DetailSerializer,
        },
        description="Save a service class by its name: 201 when it is new, 200 when a class "
        "of that name got this target and weight (for every customer in it).",
    ),
)
class ServiceClassViewSet(
    mixins.ListModelMixin,
    mixins.RetrieveModelMixin,
    viewsets.GenericViewSet,  # type: ignore[type-arg]
):
    """The service classes (staff only): a p95 target for the time from a task's request to
    its reading, which admission keeps by holding a class's new VVs while the fleet misses
    it, and the weight the planners give its requests. A customer is put in one with
    ``service_class`` on /api/v1/customers/{id}/."""

    permission_classes = [IsAuthenticated, StaffPermission]
    serializer_class = ServiceClassListSerializer
    staff_model = ServiceClass

    def get_queryset(self) -> QuerySet[ServiceClass]:
        return ServiceClass.objects.annotate(customer_count=Count("customers")).order_by("name")

    def get_object(self) -> ServiceClass:
        try:
            return self.get_queryset().get(pk=object_id(self.kwargs["pk"]))
        except (ValueError, ServiceClass.DoesNotExist):
            raise NotFound(f"No service class with id {self.kwargs['pk']!r}.") from None

    def handle_exception(self, exc: Exception) -> Response:
        if isinstance(exc, DjangoValidationError):
            exc = refusal(exc)
        return super().handle_exception(exc)

    def create(self, request: Request) -> Response:
        given = ServiceClassInSerializer(data=request.data)
        given.is_valid(raise_exception=True)
        new = not ServiceClass.objects.filter(name=given.validated_data["name"]).exists()
        saved = service_class_save(**given.validated_data)
        shown = self.get_queryset().get(pk=saved.pk)
        code = status.HTTP_201_CREATED if new else status.HTTP_200_OK
        return Response(self.get_serializer(shown).data, status=code)
