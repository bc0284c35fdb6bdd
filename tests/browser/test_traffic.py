"""The traffic check itself: a request a page drops because the test left the page is not a
failure, the same request failing on a page that stays is one."""

from __future__ import annotations

import contextlib

import pytest
from playwright.sync_api import Browser, Error, Route

from tests.browser.traffic import Traffic

ORIGIN = "http://cpcc.test"
PAGE = (
    '<html><head><link rel="icon" href="data:,"><script src="/slow.js"></script></head>'
    "<body>{}</body></html>"
)


def serve(route: Route, held: list[Route], abort: bool) -> None:
    path = route.request.url.removeprefix(ORIGIN)
    if path == "/slow.js":
        if abort:
            route.abort("aborted")
        else:
            held.append(route)  # never answered: the script is on its way when the page is left
    else:
        route.fulfill(status=200, content_type="text/html", body=PAGE.format(path))


@pytest.mark.parametrize("abort", [False, True], ids=["left", "stayed"])
def test_a_script_aborted_counts_as_failed_only_when_its_page_stays(
    browser: Browser, abort: bool
) -> None:
    context = browser.new_context()
    held: list[Route] = []
    try:
        traffic = Traffic(context, ORIGIN)
        context.route(f"{ORIGIN}/**", lambda route: serve(route, held, abort))
        page = context.new_page()
        with page.expect_event(
            "requestfailed" if abort else "request",
            predicate=lambda request: request.url.endswith("/slow.js"),
        ):
            page.goto(f"{ORIGIN}/one", wait_until="commit")
        if abort:
            with pytest.raises(AssertionError, match=r"failed: GET http://cpcc.test/slow.js"):
                traffic.assert_clean()
        else:
            with page.expect_event("requestfailed"):
                page.goto(f"{ORIGIN}/two", wait_until="commit")
            traffic.assert_clean()
    finally:
        for route in held:  # the page's request is gone already, or goes with the context
            with contextlib.suppress(Error):
                route.abort()
        context.close()
