"""The batteries of the fleet (staff): each one's logbook (cycles, flights, hours, lowest
charge), whether it is retired, and its maintenance limits due soon or overdue."""

from __future__ import annotations

from typing import Any

from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiParameter, extend_schema
from rest_framework import generics
from rest_framework.exceptions import ValidationError
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response

from cpcc_site.api import DetailSerializer
from cpcc_site.permissions import StaffPermission
from fleet.api.serializers import BatteryOutSerializer
from fleet.maintenance import battery_due_list, battery_list, battery_logbook
from fleet.models import Battery

FLAGS = {"true": True, "false": False}


class BatteryListView(generics.GenericAPIView):  # type: ignore[type-arg]
    """Every battery, by name: its logbook (cycles: a charge from below 50 % to above 90 %
    counts one), the RV it is in, whether it is retired, and its limits due soon or overdue
    (``due``). ``?retired=true`` only the retired ones, ``false`` those in use."""

    permission_classes = [IsAuthenticated, StaffPermission]
    staff_model = Battery
    serializer_class = BatteryOutSerializer
    noun = "battery"

    @extend_schema(
        parameters=[
            OpenApiParameter("retired", OpenApiTypes.BOOL, description="only retired, or not")
        ],
        responses={200: BatteryOutSerializer(many=True), 403: DetailSerializer},
    )
    def get(self, request: Request) -> Response:
        raw = request.query_params.get("retired")
        if raw is not None and raw not in FLAGS:
            raise ValidationError({"retired": [f"{raw!r}: true or false."]})
        page: Any = self.paginate_queryset(
            battery_list(retired=None if raw is None else FLAGS[raw])
        )
        batteries = list(page)
        due = battery_due_list(batteries=batteries)
        rows = [
            battery_logbook(battery=b) | {"due": [d.as_dict() for d in due[b.pk]]}
            for b in batteries
        ]
        return self.get_paginated_response(BatteryOutSerializer(rows, many=True).data)
