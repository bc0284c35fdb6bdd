"""Routes of the SDC, vehicle and ground-station endpoints."""

from django.urls import path
from rest_framework.routers import SimpleRouter

from fleet.api.service_area import ServiceAreaView
from fleet.api.views import GroundStationViewSet, SensorListView, VehicleViewSet

router = SimpleRouter()
router.register("vehicles", VehicleViewSet, basename="vehicle")
router.register("ground-stations", GroundStationViewSet, basename="ground-station")

urlpatterns = [
    path("sensors/", SensorListView.as_view(), name="sensor-list"),
    path("service-area/", ServiceAreaView.as_view(), name="service-area"),
    *router.urls,
]
