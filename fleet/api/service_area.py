"""``GET /api/v1/service-area/``: where the platform can serve tasks now, for everyone who may
submit VVs (the program editor's map draws it). It never names a vehicle."""

from __future__ import annotations

from drf_spectacular.utils import extend_schema
from rest_framework import generics, serializers
from rest_framework.request import Request
from rest_framework.response import Response

from fleet.selectors import service_area


class ServiceAreaPropertiesSerializer(serializers.Serializer):
    kind = serializers.ChoiceField(
        choices=["service", "no_fly"],
        help_text="service: some vehicle may serve a task here at these altitudes; no_fly: no "
        "task is served here at these altitudes.",
    )
    min_altitude_m = serializers.FloatField(help_text="Metres above ground, included.")
    max_altitude_m = serializers.FloatField(
        allow_null=True, help_text="Metres above ground, included; null: no ceiling (no_fly)."
    )


class ServiceAreaGeometrySerializer(serializers.Serializer):
    type = serializers.ChoiceField(choices=["Polygon", "MultiPolygon"])
    coordinates = serializers.JSONField(
        help_text="GeoJSON (RFC 7946) coordinates: [lng, lat] pairs, outer rings counter-clockwise."
    )


class ServiceAreaFeatureSerializer(serializers.Serializer):
    type = serializers.ChoiceField(choices=["Feature"])
    geometry = ServiceAreaGeometrySerializer()
    properties = ServiceAreaPropertiesSerializer()


class ServiceAreaSerializer(serializers.Serializer):
    """A GeoJSON FeatureCollection: the bands of the service area, lowest first, then the
    no-fly zones."""

    type = serializers.ChoiceField(choices=["FeatureCollection"])
    features = ServiceAreaFeatureSerializer(many=True)


class ServiceAreaView(generics.GenericAPIView):  # type: ignore[type-arg]
    """Where the platform can serve a task now: the operation areas of the vehicles in service
    merged per altitude band (a task inside a band's ground, at an altitude of the band, can
    be served, unless a no-fly zone holds it), and the no-fly zones. It says nothing of which
    vehicles there are."""

    serializer_class = ServiceAreaSerializer

    @extend_schema(responses={200: ServiceAreaSerializer})
    def get(self, request: Request) -> Response:
        return Response(service_area())
