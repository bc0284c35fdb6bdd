"""The pages' Content Security Policy: scripts, styles, pictures and sockets from this site only.

Every HTML response gets a ``Content-Security-Policy`` header (unless a view set one): scripts
only from this site's static files (no inline script: pages pass data through ``json_script``
and ``data-`` attributes), styles from this site (inline style attributes allowed: Leaflet and
the admin position elements with them), pictures from this site, ``data:``/``blob:`` URLs and
the map tile server of ``CPCC_MAP_TILES``, WebSocket connections to this host, no plugins, no
framing. The third-party API documentation pages (Swagger UI, ReDoc) start themselves with an
inline script: they alone may run inline scripts.
"""

from __future__ import annotations

from collections.abc import Callable
from urllib.parse import urlsplit

from django.conf import settings
from django.http import HttpRequest, HttpResponse, JsonResponse

HEADER = "Content-Security-Policy"
# Pages of third-party UIs that start with an inline script; they show no customer content.
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


def policy(request: HttpRequest) -> str:
    host = request.get_host()
    tiles = tile_origin(settings.CPCC_MAP_TILES)
    inline = " 'unsafe-inline'" if request.path.startswith(INLINE_SCRIPT_PATHS) else ""
    directives = [
        "default-src 'self'",
        f"script-src 'self'{inline}",
        "style-src 'self' 'unsafe-inline'",
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
            response[HEADER] = policy(request)
        return response
