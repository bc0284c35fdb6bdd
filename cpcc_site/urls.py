"""URL routes of the web application.

MEDIA_ROOT is not served here in any mode, not even with DEBUG on: its camera pictures belong to
the customer whose VV took them, and the REST API serves each one only to that customer
(``/api/v1/vvs/{id}/images/{file}``, session or token).
"""

from django.contrib import admin
from django.urls import include, path
from drf_spectacular.views import (
    SpectacularAPIView,
    SpectacularRedocView,
    SpectacularSwaggerView,
)

urlpatterns = [
    path("admin/", admin.site.urls),
    path("accounts/", include("django.contrib.auth.urls")),
    path("api/v1/", include("missions.api.urls")),
    path("api/v1/", include("fleet.api.urls")),
    path("api/v1/", include("accounts.api.urls")),
    path("api/schema/", SpectacularAPIView.as_view(), name="schema"),
    path("api/docs/", SpectacularSwaggerView.as_view(url_name="schema"), name="api-docs"),
    path(
        "api/redoc/",
        # drf-spectacular's own ReDoc page loads web fonts from Google: ours works offline.
        SpectacularRedocView.as_view(url_name="schema", template_name="api/redoc.html"),
        name="api-redoc",
    ),
    path("", include("missions.urls")),
]
