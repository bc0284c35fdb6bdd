"""A web server that stops cleanly: the requests in progress end before the server does.

Under daphne a request's synchronous part (Django's middleware and views) runs in a thread that
hands work back to the server's event loop and waits for it (Django adapts the middleware chain
to ASGI that way). On SIGTERM daphne cancels the requests' coroutines and stops the loop, but
their threads go on, wait for the stopped loop for ever, and the interpreter waits for them at
exit: a server stopped under load never ended (seen with 4 clients submitting, issue 20). So
the outermost middleware counts the requests in progress, and daphne's reactor waits, before it
shuts down, until none is left (at most ``DRAIN_S``); the process then exits with status 0.
Meanwhile a new request (on a connection kept open) is answered 503 with Retry-After: nothing
was done, and it can be sent again to the server that takes over.
"""

from __future__ import annotations

import sys
import threading
import time
from collections.abc import Callable
from typing import Any

from django.http import HttpRequest, HttpResponse, JsonResponse

DRAIN_S = 20.0
_POLL_S = 0.05

RETRY_AFTER_S = 2

_lock = threading.Lock()
_in_progress = 0
_stopping = threading.Event()


def requests_in_progress() -> int:
    return _in_progress


class InProgressMiddleware:
    """Counts the requests in progress in this process (the first middleware: it wraps the
    whole of a request's work in its thread)."""

    def __init__(self, get_response: Callable[[HttpRequest], HttpResponse]) -> None:
        self.get_response = get_response

    def __call__(self, request: HttpRequest) -> HttpResponse:
        global _in_progress
        with _lock:
            _in_progress += 1
        try:
            if _stopping.is_set():
                return _stopping_response()
            return self.get_response(request)
        finally:
            with _lock:
                _in_progress -= 1


def _stopping_response() -> HttpResponse:
    response = JsonResponse(
        {"detail": "The server is stopping: nothing was done. Send the request again in "
                   f"{RETRY_AFTER_S} s."},
        status=503,
    )  # fmt: skip
    response["Retry-After"] = str(RETRY_AFTER_S)
    response["Connection"] = "close"
    return response


def drain_before_shutdown(*, timeout_s: float = DRAIN_S) -> None:
    """Under daphne (its Twisted reactor installed), make the reactor's shutdown wait for the
    requests in progress. Anywhere else, nothing."""
    reactor: Any = sys.modules.get("twisted.internet.reactor")
    if reactor is None:
        return
    from twisted.internet import defer

    def drain() -> Any:
        _stopping.set()
        done: Any = defer.Deferred()
        deadline = time.monotonic() + timeout_s

        def check() -> None:
            if _in_progress == 0 or time.monotonic() > deadline:
                done.callback(None)
            else:
                reactor.callLater(_POLL_S, check)

        check()
        return done

    reactor.addSystemEventTrigger("before", "shutdown", drain)
