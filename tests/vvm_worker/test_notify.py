"""The webhook transport (vvm_worker/notify.py, no Django): the signature, which addresses are
refused, and what a POST reports for each way a receiver can answer, or not."""

from __future__ import annotations

import hashlib
import hmac
import socket
from collections.abc import Iterator

import pytest

from tests.accounts.receiver import Receiver, running_receiver
from vvm_worker.notify import UnsafeURL, check_url, post, sign


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
