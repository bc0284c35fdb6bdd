"""Routes of the VV endpoints: /api/v1/vvs/ and what hangs off one VV."""

from django.urls import path, re_path
from rest_framework.routers import DefaultRouter

from missions.api.downloads import VVReadingsCSVView, VVReadingsGeoJSONView, VVTrackKMLView
from missions.api.dry_run import DryRunView
from missions.api.messages import VVMessagesView
from missions.api.service_levels import ServiceLevelsView
from missions.api.views import (
    UUID_PATTERN,
    VirtualVehicleViewSet,
    VVImageView,
    VVLogView,
    VVResultsView,
    VVStorageItemView,
    VVStorageListView,
    VVTaskListView,
)

router = DefaultRouter()
router.register("vvs", VirtualVehicleViewSet, basename="vv")

ONE_VV = rf"^vvs/(?P<id>{UUID_PATTERN})/"

urlpatterns = [
    path("vvs/dry-run/", DryRunView.as_view(), name="vv-dry-run"),  # before vvs/{id}/
    path("service-levels/", ServiceLevelsView.as_view(), name="service-levels"),
    *router.urls,
    re_path(ONE_VV + r"storage/$", VVStorageListView.as_view(), name="vv-storage"),
    # A key is any non-empty string: dots, slashes, spaces, even line breaks (percent-encoded).
    re_path(
        ONE_VV + r"storage/(?P<key>[\s\S]+)/$",
        VVStorageItemView.as_view(),
        name="vv-storage-item",
    ),
    re_path(ONE_VV + r"images/(?P<file>[^/]+)$", VVImageView.as_view(), name="vv-image"),
    re_path(ONE_VV + r"tasks/$", VVTaskListView.as_view(), name="vv-tasks"),
    re_path(ONE_VV + r"log/$", VVLogView.as_view(), name="vv-log"),
    re_path(ONE_VV + r"messages/$", VVMessagesView.as_view(), name="vv-messages"),
    re_path(ONE_VV + r"results\.zip$", VVResultsView.as_view(), name="vv-results"),
    re_path(ONE_VV + r"readings\.csv$", VVReadingsCSVView.as_view(), name="vv-readings-csv"),
    re_path(
        ONE_VV + r"readings\.geojson$", VVReadingsGeoJSONView.as_view(), name="vv-readings-geojson"
    ),
    re_path(ONE_VV + r"track\.kml$", VVTrackKMLView.as_view(), name="vv-track-kml"),
]
