"""The webhook transport (vvm_worker/delivery.py, no Django): the signature, which addresses are
refused, and what a POST reports for each way a receiver can answer, or not."""

from __future__ import annotations

import hashlib
import hmac
import socket
import threading
from collections.abc import Iterator

import pytest

from tests.accounts.receiver import Receiver, running_receiver
from vvm_worker.delivery import UnsafeURL, check_url, post, sign


@pytest.fixture
def receiver() -> Iterator[Receiver]:
    yield from running_receiver()


def resolving_to(*addresses: str):
    """A resolver that answers every name with these addresses."""

    def resolve(host, port, type=0):
        return [(socket.AF_INET, socket.SOCK_STREAM, 6, "", (a, port)) for a in addresses]

    return resolve


def test_the_signature_is_the_hex_hmac_sha256_of_the_raw_body() -> None:
    body = b'{"event":"vv.finished","id":"x"}'
    expected = hmac.new(b"whsec_k", body, hashlib.sha256).hexdigest()
    assert sign(body, "whsec_k") == f"sha256={expected}"
    assert sign(body + b" ", "whsec_k") != sign(body, "whsec_k")


def test_a_name_is_refused_for_any_private_address_it_has() -> None:
    public_and_private = resolving_to("93.184.215.14", "10.0.0.7")
    with pytest.raises(UnsafeURL, match=r"hook.example \(10.0.0.7\) is a private address"):
        check_url("https://hook.example/x", allow_private=False, resolve=public_and_private)
    assert check_url("https://hook.example/x", allow_private=True, resolve=public_and_private) == [
        "93.184.215.14",
        "10.0.0.7",
    ]
    assert check_url("https://hook.example/", allow_private=False, resolve=resolving_to("8.8.8.8"))


@pytest.mark.parametrize(
    ("address", "what"),
    [
        ("2002:7f00:1::", "a 6to4 address of 127.0.0.1, a loopback address"),
        ("2002:c0a8:101::1", "a 6to4 address of 192.168.1.1, a private address"),
        ("2001:0:7f00:1::", "a Teredo address of 127.0.0.1, a loopback address"),
        ("2001:0:808:808:0:f7ff:f5ff:fffe", "a Teredo address of 10.0.0.1, a private address"),
        ("64:ff9b::7f00:1", "a NAT64 address of 127.0.0.1, a loopback address"),
        ("64:ff9b::a9fe:a9fe", "a NAT64 address of 169.254.169.254, a link-local address"),
        ("64:ff9b:1::a00:1", "a NAT64 address for local use"),
    ],
)
def test_an_ipv6_address_carrying_a_non_public_ipv4_address_is_refused(
    address: str, what: str
) -> None:
    # A relay or a NAT64 gateway on the way unwraps these to the IPv4 address inside.
    with pytest.raises(UnsafeURL) as refused:
        check_url("https://hook.example/", allow_private=False, resolve=resolving_to(address))
    assert str(refused.value) == (
        f"hook.example ({address}) is {what}: webhooks go to addresses on the public internet only."
    )
    assert check_url("https://hook.example/", allow_private=True, resolve=resolving_to(address))


def test_a_6to4_address_of_a_public_ipv4_address_is_public() -> None:
    assert check_url(
        "https://hook.example/", allow_private=False, resolve=resolving_to("2002:808:808::1")
    ) == ["2002:808:808::1"]


@pytest.mark.parametrize(
    ("url", "problem"),
    [
        ("file:///etc/passwd", "is not an http:// or https:// URL"),
        ("http:///path", "names no host"),
        ("http://93.184.215.14:99999/", "has no valid port"),
        ("http://u:p@93.184.215.14/", "may not hold a user name or password"),
    ],
)
def test_what_is_not_a_webhook_url(url: str, problem: str) -> None:
    with pytest.raises(UnsafeURL, match=problem):
        check_url(url, allow_private=True, resolve=resolving_to("93.184.215.14"))


def test_a_post_reports_what_the_receiver_answered(receiver: Receiver) -> None:
    receiver.answers = [204, 500, 302]
    sent = {"X-CPCC-Event": "vv.finished"}
    ok = post(receiver.url, b"{}", sent, timeout_s=5, allow_private=True)
    assert (ok.ok, ok.status, ok.error) == (True, 204, "")
    failed = post(receiver.url, b"{}", sent, timeout_s=5, allow_private=True)
    assert (failed.ok, failed.status, failed.error) == (False, 500, "answered 500")
    moved = post(receiver.url, b"{}", sent, timeout_s=5, allow_private=True)
    assert (moved.ok, moved.status, moved.error) == (False, 302, "redirects are not followed")
    assert [r.headers["X-CPCC-Event"] for r in receiver.requests] == ["vv.finished"] * 3
    assert receiver.requests[0].headers["User-Agent"] == "CPCC-Webhooks/1"


def test_a_post_to_an_address_refused_before_connecting_is_permanent(receiver: Receiver) -> None:
    answer = post(receiver.url, b"{}", {}, timeout_s=5, allow_private=False)
    assert answer.permanent and answer.status is None and "loopback" in answer.error
    assert receiver.requests == []


def test_no_answer_is_a_failure_that_says_why() -> None:
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    refused = post(f"http://127.0.0.1:{port}/", b"{}", {}, timeout_s=5, allow_private=True)
    assert (refused.status, refused.error, refused.permanent) == (None, "connection refused", False)
    with socket.socket() as silent:  # accepts connections, never answers
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        url = f"http://127.0.0.1:{silent.getsockname()[1]}/"
        quiet = post(url, b"{}", {}, timeout_s=0.2, allow_private=True)
    assert (quiet.status, quiet.error) == (None, "no answer within 0.2 s")


def test_a_receiver_that_answers_a_byte_at_a_time_is_cut_off_at_the_timeout() -> None:
    # A header line every 0.1 s: each read is quick, the answer never ends. The timeout is
    # the whole exchange's, so it ends at 0.5 s, not after the receiver's 5 s.
    stop = threading.Event()

    def drip(server: socket.socket) -> None:
        connection, _ = server.accept()
        with connection:
            connection.recv(65536)
            connection.sendall(b"HTTP/1.1 200 OK\r\n")
            for n in range(50):
                if stop.wait(0.1):
                    return
                try:
                    connection.sendall(f"X-Slow-{n}: x\r\n".encode())
                except OSError:
                    return

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        dripping = threading.Thread(target=drip, args=(server,), daemon=True)
        dripping.start()
        url = f"http://127.0.0.1:{server.getsockname()[1]}/"
        answer = post(url, b"{}", {}, timeout_s=0.5, allow_private=True)
        stop.set()
        dripping.join(10)
    assert (answer.status, answer.error) == (None, "no answer within 0.5 s")
    assert 450 <= answer.duration_ms < 2500, answer.duration_ms
