"""Routes of the SDC, vehicle and ground-station endpoints."""

from django.urls import path
from rest_framework.routers import SimpleRouter

from fleet.api.batteries import BatteryListView
from fleet.api.flights import FlightCSVView, FlightDetailView, FlightListView, FlightLogView
from fleet.api.service_area import ServiceAreaView
from fleet.api.views import GroundStationViewSet, SensorListView, VehicleViewSet

router = SimpleRouter()
router.register("vehicles", VehicleViewSet, basename="vehicle")
router.register("ground-stations", GroundStationViewSet, basename="ground-station")

urlpatterns = [
    path("sensors/", SensorListView.as_view(), name="sensor-list"),
    path("service-area/", ServiceAreaView.as_view(), name="service-area"),
    path("batteries/", BatteryListView.as_view(), name="battery-list"),
    path("flights/", FlightListView.as_view(), name="flight-list"),
    path("flights/export.csv", FlightCSVView.as_view(), name="flight-csv"),
    path("flights/<str:pk>/", FlightDetailView.as_view(), name="flight-detail"),
    path("flights/<str:pk>/log.tlog", FlightLogView.as_view(), name="flight-log"),
    *router.urls,
]
