"""Error pages: JSON under /api/ (what an API client can read), the site's own pages elsewhere.

Under /api/ every answer is JSON whatever DEBUG is: Django answers an unmatched path
(``/api/v1/vvs/null/log/``) or a refused host with an HTML page (its debug page with DEBUG on,
the site's 404.html with it off); ``JsonUnderApiMiddleware`` turns each into the API's JSON.

While the database is unavailable (cpcc_site.database), every request that needs it answers
503 with Retry-After, not 500: nothing is wrong with the request, and it can be sent again.
"""

from __future__ import annotations

import logging
import sys
from collections.abc import Callable
from http import HTTPStatus

from django.http import HttpRequest, HttpResponse, JsonResponse
from django.template.loader import render_to_string
from django.views import defaults

from cpcc_site import database

API_PREFIX = "/api/"
logger = logging.getLogger("cpcc.web")


def _not_found_json(request: HttpRequest) -> JsonResponse:
    return JsonResponse(
        {"detail": f"No API endpoint at {request.path} (see /api/docs/)."}, status=404
    )


def server_error(request: HttpRequest) -> HttpResponse:
    # Called while the exception is handled: an outage met outside a view (a session saved
    # by the middleware, say) is a 503 too.
    exc = sys.exc_info()[1]
    if exc is not None and database.is_outage(exc):
        return service_unavailable(request)
    if request.path.startswith(API_PREFIX):
        return JsonResponse(
            {"detail": "Server error: the request was not completed. Try again; if it keeps "
                       "happening, tell the operator the time and the path."},
            status=500,
        )  # fmt: skip
    return defaults.server_error(request)


def service_unavailable(request: HttpRequest) -> HttpResponse:
    retry = str(database.RETRY_AFTER_S)
    if request.path.startswith(API_PREFIX):
        response: HttpResponse = JsonResponse(
            {"detail": "The platform's database is unavailable for a moment: nothing was "
                       f"changed. Send the request again in {retry} s."},
            status=503,
        )  # fmt: skip
    else:
        # A page of its own: the site's base template asks the database who is logged in.
        html = render_to_string("503.html", {"retry_after_s": retry})
        response = HttpResponse(html, status=503)
    response["Retry-After"] = retry
    return response


class DatabaseOutageMiddleware:
    """503 instead of 500 when a view meets a database outage."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        return self.get_response(request)

    def process_exception(self, request: HttpRequest, exception: Exception) -> HttpResponse | None:
        if not database.is_outage(exception):
            return None
        logger.warning("database unavailable: 503", extra={"path": request.path})
        return service_unavailable(request)


def _is_json(response: HttpResponse) -> bool:
    kind = response.get("Content-Type", "").split(";")[0].strip()
    return kind == "application/json" or kind.endswith("+json")


def _phrase(code: int) -> str:
    try:
        status = HTTPStatus(code)
    except ValueError:
        return f"HTTP {code}."
    return f"{status.phrase}: {status.description}."


class JsonUnderApiMiddleware:
    """Under /api/ an error answer that is not JSON (Django's debug 404 page for a path no
    route matches, its 400 page for a refused host, ...) becomes the API's JSON with the same
    status and headers."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        response = self.get_response(request)
        if (
            response.status_code < 400
            or not request.path.startswith(API_PREFIX)
            or _is_json(response)
            or response.streaming
        ):
            return response
        if response.status_code == 404:
            answer: HttpResponse = _not_found_json(request)
        else:
            answer = JsonResponse(
                {"detail": _phrase(response.status_code)}, status=response.status_code
            )
        for header, value in response.items():
            if header.lower() not in ("content-type", "content-length"):
                answer[header] = value
        return answer
