"""What a browser context asked the platform, and what went wrong: every response of 400 or
more, every request that failed (styles, scripts, images, fonts, the socket), every request to
anything but the platform (no page may load from the internet), every uncaught script error
and console error, every breach of the pages' Content Security Policy (a script, a style or a
picture the policy refused: cpcc_site/security.py), and every WebSocket that never got its
first message (unless its page moved on first)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any
from urllib.parse import urlsplit

from playwright.sync_api import BrowserContext, ConsoleMessage, Page, Request, Response, WebSocket

ICON_SCRIPT = """
document.addEventListener('DOMContentLoaded', function () {
  if (window.top !== window || !/^https?:/.test(location.href)) return;
  var link = document.querySelector('link[rel~="icon"]');
  window.__cpccTrafficIcon(link ? link.href : null);
});
document.addEventListener('securitypolicyviolation', function (e) {
  window.__cpccTrafficPolicy({
    directive: e.effectiveDirective || e.violatedDirective, blocked: e.blockedURI,
    sample: e.sample, source: e.sourceFile, line: e.lineNumber
  });
});
"""


class Traffic:
    """Watches one browser context from its creation; ``assert_clean()`` at the end."""

    def __init__(
        self,
        context: BrowserContext,
        base_url: str,
        server_log: Callable[[], str] | None = None,
    ) -> None:
        self.context = context
        self.server_log = server_log
        self.origin = urlsplit(base_url).netloc
        self.problems: list[str] = []
        self.responses: list[tuple[int, str]] = []
        self.sockets: list[dict[str, Any]] = []
        self.expected: set[tuple[int, str]] = set()
        # How many documents each page has begun to load, and that count when each request
        # was sent: a request aborted after its page began loading another document was left.
        self.navigations: dict[Page, int] = {}
        self.sent_at: dict[Request, tuple[Page, int]] = {}
        context.on("request", self._request)
        context.on("response", self._response)
        context.on("requestfailed", self._failed)
        context.on("page", self._page)
        for page in context.pages:
            self._page(page)
        # Which icon each page declares: Chromium asks for it (or for /favicon.ico when none is
        # declared) outside the page, where Playwright does not see the request.
        self.icons: list[tuple[str, str | None]] = []
        context.expose_binding("__cpccTrafficIcon", self._icon)
        context.expose_binding("__cpccTrafficPolicy", self._policy)
        context.add_init_script(ICON_SCRIPT)

    def expect(self, status: int, path: str) -> None:
        """A refusal the test asks for itself (e.g. another customer's VV is a 404)."""
        self.expected.add((status, path))

    def _icon(self, source: dict, href: str | None) -> None:
        self.icons.append((source["frame"].url, href))

    def _policy(self, source: dict, breach: dict) -> None:
        where = f" at {breach['source']}:{breach['line']}" if breach.get("source") else ""
        sample = f" ({breach['sample']!r})" if breach.get("sample") else ""
        self.problems.append(
            f"CSP on {source['frame'].url}: {breach['directive']} refused "
            f"{breach.get('blocked') or 'inline'}{sample}{where}"
        )

    def _page(self, page: Page) -> None:
        page.on("websocket", lambda socket: self._socket(page, socket))
        page.on("request", lambda request: self._navigating(page, request))
        page.on("pageerror", lambda error: self.problems.append(f"script error: {error}"))
        page.on("console", self._console)

    def _console(self, message: ConsoleMessage) -> None:
        # "Failed to load resource" repeats a response or failure recorded below.
        if message.type == "error" and not message.text.startswith("Failed to load resource"):
            self.problems.append(f"console error on {message.location['url']}: {message.text}")

    def _request(self, request: Request) -> None:
        parts = urlsplit(request.url)
        if parts.scheme in ("http", "https", "ws", "wss") and parts.netloc != self.origin:
            self.problems.append(f"request outside the platform: {request.method} {request.url}")
        page = self._page_of(request)
        if page is not None and not request.is_navigation_request():
            self.sent_at[request] = (page, self.navigations.get(page, 0))

    @staticmethod
    def _page_of(request: Request) -> Page | None:
        try:
            return request.frame.page
        except Exception:  # a service worker's request, or its frame is gone
            return None

    def _left(self, request: Request) -> bool:
        """Its page moved on to another document (or closed) after the request was sent."""
        sent = self.sent_at.get(request)
        if sent is None:
            return False
        page, navigations = sent
        return page.is_closed() or self.navigations.get(page, 0) > navigations

    def _response(self, response: Response) -> None:
        parts = urlsplit(response.url)
        self.responses.append((response.status, response.url))
        if response.status >= 400 and (response.status, parts.path) not in self.expected:
            self.problems.append(f"{response.status} {response.request.method} {response.url}")

    def _failed(self, request: Request) -> None:
        if request.failure == "net::ERR_ABORTED" and request.resource_type in ("document", "fetch"):
            # Left before it came: the test moved on (a navigation, a download), not an error.
            return
        if request.failure == "net::ERR_ABORTED" and urlsplit(request.url).path.startswith(
            "/tiles/"
        ):
            # A map tile the map dropped on its way: its view changed, or the page was left.
            return
        if request.failure == "net::ERR_ABORTED" and self._left(request):
            # A script, style or picture of a page the test left before it came.
            return
        self.problems.append(f"failed: {request.method} {request.url} ({request.failure})")

    def _navigating(self, page: Page, request: Request) -> None:
        """The page leaves its document: its sockets close, whatever they had received."""
        if request.is_navigation_request() and request.frame == page.main_frame:
            self.navigations[page] = self.navigations.get(page, 0) + 1
            for entry in self.sockets:
                if entry["page"] is page and not entry["closed"]:
                    entry["left"] = True

    def _socket(self, page: Page, socket: WebSocket) -> None:
        entry = {"url": socket.url, "on": page.url, "page": page, "received": 0}
        entry.update(closed=False, left=False)
        self.sockets.append(entry)

        def received(_payload: object) -> None:
            entry["received"] += 1

        def closed(_socket: WebSocket) -> None:
            entry["closed"] = True

        socket.on("framereceived", received)
        socket.on("close", closed)
        socket.on(
            "socketerror", lambda error: self.problems.append(f"socket {socket.url}: {error}")
        )

    def _pump(self, seconds: float) -> None:
        """Let Playwright deliver the events that are on their way."""
        pages = [p for p in self.context.pages if not p.is_closed()]
        if pages:
            pages[0].wait_for_timeout(seconds * 1000)
        else:
            time.sleep(seconds)

    def _icon_problems(self) -> list[str]:
        pages: dict[str, list[str]] = {}
        for page_url, href in self.icons:
            icon = href or f"{urlsplit(page_url).scheme}://{self.origin}/favicon.ico"
            if not icon.startswith("data:"):
                pages.setdefault(icon, []).append(urlsplit(page_url).path)
        problems = []
        for icon, paths in pages.items():
            status = self.context.request.get(icon).status
            if status != 200:
                problems.append(f"{status} GET {icon}: the icon of {', '.join(sorted(set(paths)))}")
        return problems

    def assert_clean(self, timeout: float = 5.0) -> None:
        deadline = time.monotonic() + timeout
        while any(s["received"] == 0 and not (s["closed"] or s["left"]) for s in self.sockets):
            if time.monotonic() > deadline:
                break
            self._pump(0.05)
        self._pump(0.05)
        problems = self.problems + [
            f"socket got nothing: {s['url']} (opened on {s['on']})"
            for s in self.sockets
            if s["received"] == 0 and not s["left"]
        ]
        problems += self._icon_problems()
        if problems and self.server_log is not None:
            problems.append(f"--- the server's log:\n{self.server_log()}")
        assert not problems, "\n".join(problems)
