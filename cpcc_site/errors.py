"""Error pages: JSON under /api/ (what an API client can read), Django's pages elsewhere."""

from __future__ import annotations

from django.http import HttpRequest, HttpResponse, JsonResponse
from django.views import defaults

API_PREFIX = "/api/"


def not_found(request: HttpRequest, exception: Exception) -> HttpResponse:
    if request.path.startswith(API_PREFIX):
        return JsonResponse(
            {"detail": f"No API endpoint at {request.path} (see /api/docs/)."}, status=404
        )
    return defaults.page_not_found(request, exception)


def server_error(request: HttpRequest) -> HttpResponse:
    if request.path.startswith(API_PREFIX):
        return JsonResponse(
            {"detail": "Server error: the request was not completed. Try again; if it keeps "
                       "happening, tell the operator the time and the path."},
            status=500,
        )  # fmt: skip
    return defaults.server_error(request)
