"""The API's browsable docs, served offline.

ReDoc's bundle (drf-spectacular-sidecar) shows an "API docs by Redocly" footer whose logo it
loads from Redocly's CDN; the page would make a request to the internet on every visit. The
bundle is served here with that one address pointed at this site's own icon.
"""

from __future__ import annotations

import functools

from django.contrib.staticfiles import finders
from django.http import HttpRequest, HttpResponse
from django.templatetags.static import static
from drf_spectacular.views import SpectacularRedocView

REDOC_BUNDLE = "drf_spectacular_sidecar/redoc/bundles/redoc.standalone.js"
REDOCLY_LOGO = "https://cdn.redoc.ly/redoc/logo-mini.svg"


@functools.cache
def _offline_bundle(logo: str) -> bytes:
    path = finders.find(REDOC_BUNDLE)
    if path is None:
        raise FileNotFoundError(REDOC_BUNDLE)
    with open(path, "rb") as bundle:
        return bundle.read().replace(REDOCLY_LOGO.encode(), logo.encode())


def redoc_bundle(request: HttpRequest) -> HttpResponse:
    response = HttpResponse(
        _offline_bundle(static("img/favicon.svg")), content_type="text/javascript"
    )
    response["Cache-Control"] = "public, max-age=86400"
    return response


class OfflineRedocView(SpectacularRedocView):
    """ReDoc with the bundle above and no web fonts (templates/api/redoc.html)."""

    template_name = "api/redoc.html"

    @staticmethod
    def _redoc_standalone() -> str:
        return "/api/redoc/redoc.standalone.js"
