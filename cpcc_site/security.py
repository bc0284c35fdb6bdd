"""The pages' Content Security Policy: scripts, styles, pictures and sockets from this site only.

Every HTML response gets a ``Content-Security-Policy`` header (unless a view set one): scripts
only from this site's static files (no inline script: pages pass data through ``json_script``
and ``data-`` attributes), styles only from this site's stylesheets (no ``style`` attribute, no
``<style>`` element: the templates use classes; Leaflet and the admin's scripts position
elements through the CSSOM, ``element.style.top = ...``, which the policy leaves alone),
pictures from this site, ``data:``/``blob:`` URLs and the map tile server of
``CPCC_MAP_TILES``, WebSocket connections to this host, no plugins, no framing. The third-party
API documentation pages (Swagger UI, ReDoc) start themselves with an inline script and style
themselves inline: they alone may run inline scripts and apply inline styles (they show the
API's schema, nothing a customer wrote); so may Django's error pages of development (DEBUG)
apply their inline styles. tests/test_html_sinks.py keeps the templates and scripts to this.
"""

from __future__ import annotations

from collections.abc import Callable
from urllib.parse import urlsplit

from django.conf import settings
from django.http import HttpRequest, HttpResponse, JsonResponse

HEADER = "Content-Security-Policy"
# Pages of third-party UIs that start with an inline script and style themselves inline (ReDoc's
# styled-components add <style> elements); they show no customer content.
INLINE_SCRIPT_PATHS = ("/api/docs/", "/api/redoc/")


def tile_origin(template: str) -> str:
    """The scheme and host of a Leaflet tile URL template ("" for none)."""
    if not template:
        return ""
    parts = urlsplit(template.replace("{s}", "a"))
    host = parts.netloc
    if "{s}." in template:
        host = "*." + host.split(".", 1)[1]
    return f"{parts.scheme}://{host}" if parts.scheme and host else ""


def policy(request: HttpRequest, *, debug_page: bool = False) -> str:
    """``debug_page``: one of Django's error pages of development (``DEBUG``), which style
    themselves with a ``<style>`` element."""
    host = request.get_host()
    tiles = tile_origin(settings.CPCC_MAP_TILES)
    inline = " 'unsafe-inline'" if request.path.startswith(INLINE_SCRIPT_PATHS) else ""
    inline_style = " 'unsafe-inline'" if inline or debug_page else ""
    directives = [
        "default-src 'self'",
        f"script-src 'self'{inline}",
        f"style-src 'self'{inline_style}",
        "img-src 'self' data: blob:" + (f" {tiles}" if tiles else ""),
        "font-src 'self' data:",
        f"connect-src 'self' ws://{host} wss://{host}",
        "worker-src 'self' blob:",
        "object-src 'none'",
        "base-uri 'self'",
        "form-action 'self'",
        "frame-ancestors 'none'",
    ]
    return "; ".join(directives)


class RequestSizeLimitMiddleware:
    """413 with a JSON body for a request whose body is larger than CPCC_MAX_REQUEST_BYTES (by
    its Content-Length), before anything reads it."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        limit = settings.CPCC_MAX_REQUEST_BYTES
        try:
            length = int(request.META.get("CONTENT_LENGTH") or 0)
        except ValueError:
            return JsonResponse({"detail": "Content-Length is not a number."}, status=400)
        if length > limit:
            return JsonResponse(
                {"detail": f"The request body has {length:,} bytes; at most {limit:,} are "
                           "accepted (CPCC_MAX_REQUEST_BYTES)."},
                status=413,
            )  # fmt: skip
        return self.get_response(request)


class ContentSecurityPolicyMiddleware:
    """Adds the policy above to HTML responses."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        response = self.get_response(request)
        content_type = response.get("Content-Type", "")
        if HEADER not in response and content_type.startswith("text/html"):
            # With DEBUG, an error is Django's technical 404 or 500 page (never in production).
            debug_page = settings.DEBUG and response.status_code >= 400
            response[HEADER] = policy(request, debug_page=debug_page)
        return response
