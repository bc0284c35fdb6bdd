"""Notifications: the interface through which the services say that a VV ended or a task was
done, and the webhook transport (the signature, the address check, the POST, the back-off).

No Django here. The services tell a `Notifier` (the VVM's) only about events the VV's customer
listens for; in the distributed platform `vvm_worker.celery_dispatch.CeleryNotifier` sends one
Celery message once the transaction commits, and the workers on the ``notify`` queue deliver
it (vvm_worker/tasks.py). ``simulate`` and most tests use `Unheard`.

The address check is done when a webhook is made and again at every delivery, and the POST
goes to the very address that was checked (the host name is not resolved a second time by the
connection, which a DNS answer that changes in between could otherwise point at this
machine's own services). Redirects are not followed, for the same reason.
"""

from __future__ import annotations

import hashlib
import hmac
import http.client
import ipaddress
import socket
import ssl
import time
import urllib.parse
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

# The Celery tasks (vvm_worker/tasks.py) by name, and the queue the ground-station workers
# serve them on (one may run a worker of its own: `celery -A cpcc_site worker -Q notify`).
NOTIFY_TASK = "cpcc.notify"
WEBHOOK_DELIVER_TASK = "cpcc.webhook_deliver"
NOTIFY_QUEUE = "notify"

SIGNATURE_HEADER = "X-CPCC-Signature"
EVENT_HEADER = "X-CPCC-Event"
DELIVERY_HEADER = "X-CPCC-Delivery"
USER_AGENT = "CPCC-Webhooks/1"
# What is read of an answer's body (nothing of it is kept): enough to end the exchange cleanly.
ANSWER_BYTES = 64 * 1024

Resolver = Callable[..., Sequence[tuple[Any, ...]]]


class Notifier(Protocol):
    """Who hears that a VV ended or that one of its tasks was done."""

    def vv_event(
        self, *, event: str, vv_id: uuid.UUID, at_ms: int, task_id: int | None = None
    ) -> None:
        """``event`` (``vv.finished``, ``vv.failed``, ``task.done``) happened to the VV at
        ``at_ms`` (Unix epoch milliseconds, the VV's logical time); told to the customer's
        webhooks and e-mail recipients once the caller's transaction commits."""
        ...


class Unheard:
    """The notifier of ``simulate`` and of tests: nobody is told."""

    def vv_event(
        self, *, event: str, vv_id: uuid.UUID, at_ms: int, task_id: int | None = None
    ) -> None:
        pass


def sign(body: bytes, secret: str) -> str:
    """The ``X-CPCC-Signature`` of a body: ``sha256=`` and the hex HMAC-SHA256 of the raw
    body with the webhook's secret."""
    return "sha256=" + hmac.new(secret.encode(), body, hashlib.sha256).hexdigest()


def retry_delay_s(attempt: int, *, first_s: float) -> float:
    """How long to wait after attempt ``attempt`` (1, 2, ...) failed: ``first_s``, then twice
    the wait before each time (30 s, 60 s, 120 s, ...)."""
    return float(first_s * 2 ** (attempt - 1))


class UnsafeURL(ValueError):
    """A webhook URL the platform will not POST to; the message says why, for its owner."""


def check_url(
    url: str, *, allow_private: bool, resolve: Resolver = socket.getaddrinfo
) -> list[str]:
    """The addresses a webhook URL's host has, each one checked. Raises UnsafeURL for a URL
    that is not ``http(s)://host...``, holds a user name or password, has a host name that
    does not resolve, or (unless ``allow_private``) one with an address that is not on the
    public internet: loopback, private, link-local, shared, multicast, reserved."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme not in ("http", "https"):
        raise UnsafeURL(f"{url!r} is not an http:// or https:// URL.")
    if parts.username is not None or parts.password is not None:
        raise UnsafeURL("A webhook URL may not hold a user name or password.")
    host = parts.hostname
    if not host:
        raise UnsafeURL(f"{url!r} names no host.")
    try:
        port = parts.port or (443 if parts.scheme == "https" else 80)
    except ValueError:
        raise UnsafeURL(f"{url!r} has no valid port.") from None
    try:
        found = resolve(host, port, type=socket.SOCK_STREAM)
    except (OSError, UnicodeError):
        raise UnsafeURL(f"The host name {host!r} does not resolve to an address.") from None
    addresses = list(dict.fromkeys(str(info[4][0]) for info in found))
    if not addresses:
        raise UnsafeURL(f"The host name {host!r} does not resolve to an address.")
    if not allow_private:
        for address in addresses:
            kind = _not_public(address)
            if kind is not None:
                shown = host if host == address else f"{host} ({address})"
                raise UnsafeURL(
                    f"{shown} is a {kind} address: webhooks go to addresses on the public "
                    "internet only."
                )
    return addresses


def _not_public(address: str) -> str | None:
    """What kind of address this is, when it is not a public one (None when it is)."""
    ip = ipaddress.ip_address(address.split("%", 1)[0])  # an IPv6 scope (fe80::1%eth0)
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    kinds = [  # the most telling name first (0.0.0.0 and 127.0.0.1 are "private" too)
        ("unspecified", ip.is_unspecified),
        ("loopback", ip.is_loopback),
        ("link-local", ip.is_link_local),
        ("multicast", ip.is_multicast),
        ("reserved", ip.is_reserved),
        ("private", ip.is_private),
    ]
    for kind, matches in kinds:
        if matches:
            return kind
    return None if ip.is_global else "non-public"


@dataclass(frozen=True)
class Answer:
    """How one POST went: the status the receiver answered (None: no answer, ``error`` says
    why), and how long it took. ``permanent``: trying again cannot help (an unsafe URL)."""

    status: int | None
    error: str = ""
    duration_ms: int = 0
    permanent: bool = False

    @property
    def ok(self) -> bool:
        return self.status is not None and 200 <= self.status < 300


def post(
    url: str,
    body: bytes,
    headers: Mapping[str, str],
    *,
    timeout_s: float,
    allow_private: bool,
    resolve: Resolver = socket.getaddrinfo,
    clock: Callable[[], float] = time.monotonic,
) -> Answer:
    """POST ``body`` to ``url`` (after ``check_url``), to the checked addresses in turn until
    one connects; an answer other than 2xx (a redirect included) is a failure with its status.
    Never raises for what the receiver or the network does."""
    started = clock()

    def took() -> int:
        return max(0, round((clock() - started) * 1000))

    try:
        addresses = check_url(url, allow_private=allow_private, resolve=resolve)
    except UnsafeURL as exc:
        permanent = "does not resolve" not in str(exc)  # DNS may answer next time
        return Answer(None, str(exc), took(), permanent=permanent)
    parts = urllib.parse.urlsplit(url)
    target = urllib.parse.urlunsplit(("", "", parts.path or "/", parts.query, ""))
    sent = {"Content-Type": "application/json", "User-Agent": USER_AGENT, **headers}
    error = ""
    for address in addresses:
        connection = _connection(parts, address, timeout_s)
        try:
            connection.request("POST", target, body=body, headers=sent)
            response = connection.getresponse()
            response.read(ANSWER_BYTES)
            status = response.status
        except ConnectionRefusedError:
            error = "connection refused"
            continue
        except TimeoutError:
            return Answer(None, f"no answer within {timeout_s:g} s", took())
        except ssl.SSLError as exc:
            return Answer(None, f"TLS: {exc.reason or exc}", took())
        except (OSError, http.client.HTTPException) as exc:
            error = f"{type(exc).__name__}: {exc}"[:200]
            continue
        finally:
            connection.close()
        if 300 <= status < 400:
            return Answer(status, "redirects are not followed", took())
        return Answer(status, "" if 200 <= status < 300 else f"answered {status}", took())
    return Answer(None, error, took())


def _connection(
    parts: urllib.parse.SplitResult, address: str, timeout_s: float
) -> http.client.HTTPConnection:
    host = parts.hostname or ""
    if parts.scheme == "https":
        return _PinnedHTTPSConnection(host, parts.port, address=address, timeout=timeout_s)
    return _PinnedHTTPConnection(host, parts.port, address=address, timeout=timeout_s)


class _PinnedHTTPConnection(http.client.HTTPConnection):
    """HTTP to the host's name (the Host header) at an address checked before."""

    def __init__(self, host: str, port: int | None, *, address: str, timeout: float) -> None:
        super().__init__(host, port, timeout=timeout)
        self.address = address

    def connect(self) -> None:
        self.sock = socket.create_connection((self.address, self.port), self.timeout)


class _PinnedHTTPSConnection(http.client.HTTPSConnection):
    """HTTPS to the host's name (Host header, SNI and certificate) at an address checked
    before."""

    def __init__(self, host: str, port: int | None, *, address: str, timeout: float) -> None:
        super().__init__(host, port, timeout=timeout, context=ssl.create_default_context())
        self.address = address

    def connect(self) -> None:
        sock = socket.create_connection((self.address, self.port), self.timeout)
        self.sock = self._context.wrap_socket(sock, server_hostname=self.host)  # type: ignore[attr-defined]
