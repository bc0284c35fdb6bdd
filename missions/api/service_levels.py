"""``GET /api/v1/service-levels/``: how the fleet kept each customer's service class over a
period (issue 28), for platform staff only: a customer's user gets 403, as for the fleet and
the customers (the figures name every customer). Per class also what the class would have got
alone (``planning.alone``'s estimate from the period's requests) and the holds: its customers'
VVs held back for other classes, and the holds of other classes made for it; and each hold of
the period (issue 55).

The period is on the platform clock (Unix epoch seconds on the web platform): the tasks
requested from ``since`` (inclusive) to ``until`` (exclusive) and read count.
"""

from __future__ import annotations

import datetime as dt
import math
from typing import Any

from drf_spectacular.types import OpenApiTypes
from drf_spectacular.utils import OpenApiParameter, OpenApiResponse, extend_schema
from rest_framework import serializers
from rest_framework.permissions import IsAuthenticated
from rest_framework.request import Request
from rest_framework.response import Response
from rest_framework.views import APIView

from cpcc_site.api import DetailSerializer
from cpcc_site.permissions import StaffPermission
from vvm_worker.clock import SystemClock
from vvm_worker.services.service_levels import (
    HoldShown,
    service_level_holds,
    service_levels_by_class,
    service_levels_report,
)

# Without ``since``: the day before ``until`` (or from the first instant there is).
DEFAULT_PERIOD_S = 86_400.0
FIRST_S = dt.datetime.min.replace(tzinfo=dt.UTC).timestamp()


def parse_instant(text: str) -> float:
    """An instant as Unix epoch seconds: a number of seconds, or ISO 8601 (a time without a
    zone is UTC), within the years 1-9999 (UTC). Raises ValueError saying what was expected."""
    try:
        seconds = float(text)
    except ValueError:
        seconds = _iso_seconds(text)
    if not math.isfinite(seconds):
        raise ValueError(f"{text!r} is not a finite number of seconds")
    try:
        iso(seconds)
    except (OverflowError, OSError, ValueError):
        raise ValueError(f"{text!r} is not within the years 1-9999") from None
    return seconds


def _iso_seconds(text: str) -> float:
    try:
        moment = dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        raise ValueError(
            f"{text!r} is neither epoch seconds nor an ISO 8601 time (e.g. 2026-01-31T12:00:00Z)"
        ) from None
    if moment.tzinfo is None:
        moment = moment.replace(tzinfo=dt.UTC)
    try:
        return moment.timestamp()
    except (OverflowError, OSError, ValueError):
        raise ValueError(f"{text!r} is not within the years 1-9999") from None


def iso(seconds: float) -> str:
    return dt.datetime.fromtimestamp(seconds, dt.UTC).isoformat().replace("+00:00", "Z")


class PeriodInSerializer(serializers.Serializer):  # type: ignore[type-arg]
    since = serializers.CharField(required=False, help_text="epoch seconds or ISO 8601")
    until = serializers.CharField(required=False, help_text="epoch seconds or ISO 8601")

    def validate_since(self, value: str) -> float:
        return _instant(value)

    def validate_until(self, value: str) -> float:
        return _instant(value)

    def validate(self, attrs: dict[str, Any]) -> dict[str, Any]:
        until = attrs.get("until", SystemClock().now_s())
        since = attrs.get("since", max(until - DEFAULT_PERIOD_S, FIRST_S))
        if since >= until:
            raise serializers.ValidationError({"since": ["must be before until"]})
        return {"since": since, "until": until}


def _instant(value: str) -> float:
    try:
        return parse_instant(value)
    except ValueError as exc:
        raise serializers.ValidationError(str(exc)) from None


class LevelStatsOutSerializer(serializers.Serializer):  # type: ignore[type-arg]
    customer = serializers.CharField(help_text='the customer\'s name ("(all)" in a class row)')
    service_class = serializers.CharField(help_text='the class\'s name ("none": no class)')
    target_p95_s = serializers.FloatField(allow_null=True, help_text="null: no target")
    requests = serializers.IntegerField(help_text="tasks requested in the period and read")
    median_s = serializers.FloatField(help_text="median latency, request to reading")
    p95_s = serializers.FloatField(help_text="95th percentile latency (nearest rank)")
    within_target = serializers.FloatField(
        allow_null=True, help_text="share of the requests read within the target (0-1)"
    )
    meets_target = serializers.BooleanField(allow_null=True, help_text="p95 within the target")


class AloneOutSerializer(serializers.Serializer):  # type: ignore[type-arg]
    requests = serializers.IntegerField(help_text="the class's requests replayed")
    median_s = serializers.FloatField(help_text="median latency the class would get alone")
    p95_s = serializers.FloatField(help_text="95th percentile latency it would get alone")
    within_target = serializers.FloatField(allow_null=True, help_text="share within the target")
    meets_target = serializers.BooleanField(
        allow_null=True, help_text="whether the target can be kept at all with this fleet"
    )


class ClassHoldsOutSerializer(serializers.Serializer):  # type: ignore[type-arg]
    count = serializers.IntegerField(help_text="holds of the class's customers' new VVs")
    held_s = serializers.FloatField(help_text="seconds they held within the period, summed")
    for_this_class = serializers.IntegerField(
        help_text="holds of other classes' customers made to keep this class's target"
    )


class ClassLevelOutSerializer(LevelStatsOutSerializer):
    alone = AloneOutSerializer(
        allow_null=True,
        help_text="what the class's requests of the period would have got if the fleet served "
        "nobody else (an estimate: each RV replays the class's requests it read); null: none "
        "was read by an RV",
    )
    holds = ClassHoldsOutSerializer()


class HoldOutSerializer(serializers.Serializer):  # type: ignore[type-arg]
    customer = serializers.CharField(help_text="the customer whose new VVs were held back")
    service_class = serializers.CharField(help_text="its class (which had slack)")
    for_classes = serializers.ListField(
        child=serializers.CharField(), help_text="the classes missing their targets"
    )
    started = serializers.CharField(help_text="when it began (ISO 8601, UTC)")
    ended = serializers.CharField(allow_null=True, help_text="when it ended; null: it holds")
    held_s = serializers.FloatField(help_text="seconds it held within the period")
    vvs_held = serializers.IntegerField(help_text="the most VVs it held at once")
    class_p95_s = serializers.FloatField(
        allow_null=True, help_text="the held class's p95 over its recent and open tasks then"
    )
    spare_s = serializers.FloatField(help_text="the most its VVs could wait (its slack)")


class ServiceLevelsOutSerializer(serializers.Serializer):  # type: ignore[type-arg]
    since = serializers.CharField(help_text="start of the period (ISO 8601, UTC)")
    until = serializers.CharField(help_text="end of the period (ISO 8601, UTC), excluded")
    customers = LevelStatsOutSerializer(many=True, help_text="per customer and class")
    classes = ClassLevelOutSerializer(many=True, help_text="per class, all customers")
    holds = HoldOutSerializer(many=True, help_text="each hold of the period, oldest first")


def hold_shown(hold: HoldShown) -> dict[str, object]:
    """A hold as the API and the admin page show it."""
    return {
        "customer": hold.customer,
        "service_class": hold.service_class,
        "for_classes": list(hold.for_classes),
        "started": iso(hold.started_s),
        "ended": None if hold.ended_s is None else iso(hold.ended_s),
        "held_s": round(hold.held_s, 3),
        "vvs_held": hold.vvs_held,
        "class_p95_s": None if hold.class_p95_s is None else round(hold.class_p95_s, 3),
        "spare_s": round(hold.spare_s, 3),
    }


class ServiceLevelsView(APIView):
    permission_classes = [IsAuthenticated, StaffPermission]
    staff_perms = {m: ("accounts.view_serviceclass",) for m in ("GET", "HEAD", "OPTIONS")}

    @extend_schema(
        summary="Service levels per customer and class over a period (staff only)",
        parameters=[
            OpenApiParameter(
                "since",
                OpenApiTypes.STR,
                description="start (epoch seconds or ISO 8601; default: a day before until)",
            ),
            OpenApiParameter("until", OpenApiTypes.STR, description="end, excluded (default: now)"),
        ],
        responses={
            200: ServiceLevelsOutSerializer,
            400: OpenApiResponse(
                OpenApiTypes.OBJECT,
                description="since or until is malformed, or since is not before until: the "
                "body names the parameter.",
            ),
            403: DetailSerializer,
        },
    )
    def get(self, request: Request) -> Response:
        period = PeriodInSerializer(data=request.query_params)
        period.is_valid(raise_exception=True)
        since, until = period.validated_data["since"], period.validated_data["until"]
        holds = service_level_holds(since_s=since, until_s=until, now_s=SystemClock().now_s())
        classes = service_levels_by_class(since_s=since, until_s=until, holds=holds)
        return Response(
            {
                "since": iso(since),
                "until": iso(until),
                "customers": [
                    s.as_dict() for s in service_levels_report(since_s=since, until_s=until)
                ],
                "classes": [c.as_dict() for c in classes],
                "holds": [hold_shown(h) for h in holds],
            }
        )
