"""Which pages may open a WebSocket with the user's session: the site's own, exactly.

A browser sends the session cookie with a socket opened by any page, of any site; only the
``Origin`` header says whose page opened it. Channels' AllowedHostsOriginValidator compares the
origin's host with ALLOWED_HOSTS and ignores the port and the scheme, so a page served by
another program on the same machine (``http://127.0.0.1:9999``) could read the live map of a
user of this one (``http://127.0.0.1:8000``). Here, as Django's CSRF check does for forms, the
origin must be the site's own, scheme, host and port (the ``Host`` header, checked against
ALLOWED_HOSTS, and the scheme the browser used), or one listed in CSRF_TRUSTED_ORIGINS (for
a site whose public address differs from its host, behind a proxy).
"""

from __future__ import annotations

from typing import Any
from urllib.parse import urlsplit

from channels.security.websocket import WebsocketDenier
from django.conf import settings
from django.http.request import split_domain_port, validate_host
from django.utils.http import is_same_domain

Scope = dict[str, Any]
DEFAULT_PORTS = {"http": 80, "https": 443}


def _header(scope: Scope, name: bytes) -> str | None:
    for key, value in scope.get("headers", ()):
        if key == name:
            try:
                return bytes(value).decode("latin-1")
            except (TypeError, ValueError):
                return None
    return None


def _normalized(origin: str) -> tuple[str, str, int] | None:
    """An origin as (scheme, host, port), the port filled in for the scheme; None if it is
    not an http(s) origin (``null``, a file, garbage)."""
    try:
        parts = urlsplit(origin.strip().lower())
        port = parts.port
    except ValueError:
        return None
    if parts.scheme not in DEFAULT_PORTS or not parts.hostname:
        return None
    if parts.path or parts.query or parts.fragment or parts.username or parts.password:
        return None
    return parts.scheme, parts.hostname, port or DEFAULT_PORTS[parts.scheme]


def _allowed_hosts() -> list[str]:
    # As Django's HttpRequest.get_host: in development an empty list means this machine.
    hosts = list(settings.ALLOWED_HOSTS)
    if settings.DEBUG and not hosts:
        hosts = [".localhost", "127.0.0.1", "[::1]"]
    return hosts


def _is_secure(scope: Scope) -> bool:
    """Whether the browser reached the site over TLS: a ``wss`` scope, the proxy's header named
    by SECURE_PROXY_SSL_HEADER (as Django's ``request.is_secure()``), or an HTTPS-only site
    (CPCC_HTTPS: its pages, the only ones that open the socket, are all ``https://``; daphne
    does not say whether a socket came over TLS)."""
    if scope.get("scheme") in ("wss", "https"):
        return True
    proxy_header = getattr(settings, "SECURE_PROXY_SSL_HEADER", None)
    if proxy_header:
        name, secure_value = proxy_header
        header = name.removeprefix("HTTP_").replace("_", "-").lower().encode("latin-1")
        value = _header(scope, header)
        if value is not None:
            return bool(value.split(",", 1)[0].strip() == secure_value)
    return bool(getattr(settings, "CPCC_HTTPS", False))


def site_origin(scope: Scope) -> str | None:
    """The site's own origin for a socket's scope: the scheme the browser used and the ``Host``
    header, if ALLOWED_HOSTS allows that host; None otherwise."""
    host = _header(scope, b"host")
    if not host:
        return None
    domain, _port = split_domain_port(host.lower())
    if not domain or not validate_host(domain, _allowed_hosts()):
        return None
    return f"{'https' if _is_secure(scope) else 'http'}://{host.lower()}"


def origin_allowed(scope: Scope) -> bool:
    """Whether the page that opened the socket is the site's own (scheme, host and port) or
    one that CSRF_TRUSTED_ORIGINS lists (``https://*.example.com`` for every subdomain)."""
    raw = _header(scope, b"origin")
    origin = _normalized(raw) if raw else None
    if origin is None:
        return False
    own = site_origin(scope)
    if own is not None and _normalized(own) == origin:
        return True
    scheme, host, port = origin
    for trusted in settings.CSRF_TRUSTED_ORIGINS:
        if "*" in trusted:
            parts = urlsplit(trusted.lower())
            pattern = parts.netloc.lstrip("*")
            netloc = host if port == DEFAULT_PORTS[scheme] else f"{host}:{port}"
            if parts.scheme == scheme and is_same_domain(netloc, pattern):
                return True
        elif _normalized(trusted) == origin:
            return True
    return False


class SameOriginValidator:
    """ASGI middleware for WebSockets: a socket opened by a page of another origin (or without
    an ``Origin`` header) is refused before it reaches the application."""

    def __init__(self, application: Any) -> None:
        self.application = application

    async def __call__(self, scope: Scope, receive: Any, send: Any) -> Any:
        if scope["type"] != "websocket":
            raise ValueError("SameOriginValidator checks WebSocket connections only")
        if origin_allowed(scope):
            return await self.application(scope, receive, send)
        return await WebsocketDenier()(scope, receive, send)
