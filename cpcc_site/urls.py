"""URL routes of the web application.

MEDIA_ROOT is not served here in any mode, not even with DEBUG on: its camera pictures belong to
the customer whose VV took them, and the REST API serves each one only to that customer
(``/api/v1/vvs/{id}/images/{file}``, session or token).
"""

from django.contrib import admin
from django.shortcuts import redirect
from django.templatetags.static import static
from django.urls import include, path
from drf_spectacular.views import SpectacularAPIView, SpectacularSwaggerView

from cpcc_site.docs import OfflineRedocView, redoc_bundle
from fleet import views as fleet_views

urlpatterns = [
    # Browsers ask for /favicon.ico on every page that names no icon (Swagger UI, ReDoc).
    path("favicon.ico", lambda request: redirect(static("img/favicon.svg"), permanent=True)),
    path("admin/", admin.site.urls),
    path("accounts/", include("django.contrib.auth.urls")),
    path("accounts/", include("accounts.urls")),
    path("api/v1/", include("missions.api.urls")),
    path("api/v1/", include("fleet.api.urls")),
    path("api/v1/", include("accounts.api.urls")),
    path("api/schema/", SpectacularAPIView.as_view(), name="schema"),
    path("api/docs/", SpectacularSwaggerView.as_view(url_name="schema"), name="api-docs"),
    # drf-spectacular's own ReDoc page loads web fonts and a logo from the internet: ours
    # works offline (cpcc_site/docs.py).
    path("api/redoc/", OfflineRedocView.as_view(url_name="schema"), name="api-redoc"),
    path("api/redoc/redoc.standalone.js", redoc_bundle, name="api-redoc-bundle"),
    path("tiles/<int:z>/<int:x>/<int:y>.png", fleet_views.map_tile, name="map-tile"),
    path("", include("missions.urls")),
]

handler500 = "cpcc_site.errors.server_error"
