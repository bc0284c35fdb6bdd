"""Delivering notifications: the interface through which the services say that a VV ended or
a task was done, and the webhook transport (the signature, the address check, the POST, the
back-off). The database side, what a customer listens for, is services/notifications.py.

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

import contextlib
import hashlib
import hmac
import http.client
import ipaddress
import socket
import ssl
import threading
import time
import urllib.parse
import uuid
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

# The Celery tasks (vvm_worker/tasks.py) by name, and the queue `manage.py notifyworker`
# serves them on (threads of its own, never a station's or vehicle's worker thread).
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


class PerKeyLimit:
    """At most ``limit`` of something at once per key (a customer's webhook POSTs in a notify
    worker's threads), so that one slow or hostile receiver holds only its own customer's
    share of the threads. Thread-safe."""

    def __init__(self, limit: int) -> None:
        self.limit = limit
        self._lock = threading.Lock()
        self._taken: dict[object, int] = {}

    def try_take(self, key: object) -> bool:
        """One for ``key`` if it has fewer than ``limit``; False (nothing taken) otherwise."""
        with self._lock:
            taken = self._taken.get(key, 0)
            if taken >= self.limit:
                return False
            self._taken[key] = taken + 1
            return True

    def give_back(self, key: object) -> None:
        with self._lock:
            left = self._taken.get(key, 0) - 1
            if left > 0:
                self._taken[key] = left
            else:
                self._taken.pop(key, None)


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
            what = _not_public(address)
            if what is not None:
                shown = host if host == address else f"{host} ({address})"
                raise UnsafeURL(
                    f"{shown} is {what}: webhooks go to addresses on the public internet only."
                )
    return addresses


# IPv6 addresses that carry an IPv4 address a router on the way may unwrap and connect to.
_NAT64 = ipaddress.IPv6Network("64:ff9b::/96")  # RFC 6052's well-known prefix
_NAT64_LOCAL = ipaddress.IPv6Network("64:ff9b:1::/48")  # RFC 8215's, for a network's own use


def _not_public(address: str) -> str | None:
    """What this address is, when it is not a public one ("a loopback address", ...); None
    when it is. An IPv6 address that carries an IPv4 one (IPv4-mapped, 6to4, Teredo, NAT64)
    is as public as the IPv4 address inside it, and no more public than itself."""
    ip = ipaddress.ip_address(address.split("%", 1)[0])  # an IPv6 scope (fe80::1%eth0)
    if isinstance(ip, ipaddress.IPv6Address):
        if ip in _NAT64_LOCAL:
            return "a NAT64 address for local use"
        if ip.ipv4_mapped is not None:
            ip = ip.ipv4_mapped
        else:
            for carrier, inner in _carried_ipv4(ip):
                what = _not_public(str(inner))
                if what is not None:
                    return f"a {carrier} address of {inner}, {what}"
    kinds = [  # the most telling name first (0.0.0.0 and 127.0.0.1 are "private" too)
        ("an unspecified", ip.is_unspecified),
        ("a loopback", ip.is_loopback),
        ("a link-local", ip.is_link_local),
        ("a multicast", ip.is_multicast),
        ("a reserved", ip.is_reserved),
        ("a private", ip.is_private),
    ]
    for kind, matches in kinds:
        if matches:
            return f"{kind} address"
    return None if ip.is_global else "a non-public address"


def _carried_ipv4(
    ip: ipaddress.IPv6Address,
) -> list[tuple[str, ipaddress.IPv4Address]]:
    """The IPv4 addresses inside an IPv6 one, each with the name of the way it is carried."""
    carried: list[tuple[str, ipaddress.IPv4Address]] = []
    if ip.sixtofour is not None:
        carried.append(("6to4", ip.sixtofour))
    if ip.teredo is not None:
        server, client = ip.teredo
        carried += [("Teredo", server), ("Teredo", client)]
    if ip in _NAT64:
        carried.append(("NAT64", ipaddress.IPv4Address(int(ip) & 0xFFFFFFFF)))
    return carried


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
    ``timeout_s`` bounds the whole exchange (connecting, sending, the answer's headers and
    what is read of its body), not each read: a receiver that sends a byte now and then is cut
    off at it. Never raises for what the receiver or the network does."""
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
    no_answer = f"no answer within {timeout_s:g} s"
    deadline = time.monotonic() + timeout_s
    error = ""
    for address in addresses:
        left = deadline - time.monotonic()
        if left <= 0:
            return Answer(None, no_answer, took())
        connection = _connection(parts, address, left)
        cutoff = _Cutoff(connection, left)
        try:
            connection.request("POST", target, body=body, headers=sent)
            response = connection.getresponse()
            response.read(ANSWER_BYTES)
            status = response.status
        except ConnectionRefusedError:
            error = "connection refused"
            continue
        except TimeoutError:
            return Answer(None, no_answer, took())
        except (OSError, http.client.HTTPException) as exc:
            if cutoff.fired:
                return Answer(None, no_answer, took())
            if isinstance(exc, ssl.SSLError):
                return Answer(None, f"TLS: {exc.reason or exc}", took())
            error = f"{type(exc).__name__}: {exc}"[:200]
            continue
        finally:
            cutoff.cancel()
            connection.close()
        if cutoff.fired:  # what was read ended because the socket was shut at the deadline
            return Answer(None, no_answer, took())
        if 300 <= status < 400:
            return Answer(status, "redirects are not followed", took())
        return Answer(status, "" if 200 <= status < 300 else f"answered {status}", took())
    return Answer(None, error, took())


class _Cutoff:
    """Shuts a connection's socket when its time is up, whatever read or write waits on it
    (a socket's own timeout bounds each read, not the exchange)."""

    def __init__(self, connection: http.client.HTTPConnection, after_s: float) -> None:
        self._connection = connection
        self._lock = threading.Lock()
        self.fired = False
        self._timer = threading.Timer(after_s, self._fire)
        self._timer.daemon = True
        self._timer.start()

    def _fire(self) -> None:
        with self._lock:
            self.fired = True
            sock = self._connection.sock
            if sock is not None:
                with contextlib.suppress(OSError):
                    sock.shutdown(socket.SHUT_RDWR)

    def cancel(self) -> None:
        self._timer.cancel()
        with self._lock:  # a shutdown under way ends before the connection is closed
            pass


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
