"""The Account page's API tokens in Chromium: a customer makes a token, sees its key once,
uses it from a script, sees when it was last used, revokes it, and the script is refused; no
request fails and no script errs on the way."""

from __future__ import annotations

import re
import urllib.error
import urllib.request

import pytest
from playwright.sync_api import expect

from tests.browser.pages import log_in

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

KEY = re.compile(r"^cpcc_[0-9a-f]{64}$")


def api_status(base_url: str, key: str) -> int:
    """What the API answers a script that sends this token (outside the browser)."""
    request = urllib.request.Request(
        f"{base_url}/api/v1/vvs/", headers={"Authorization": f"Token {key}"}
    )
    try:
        with urllib.request.urlopen(request, timeout=10) as answer:
            return int(answer.status)
    except urllib.error.HTTPError as refused:
        return refused.code


def test_a_customer_makes_a_token_sees_it_once_uses_it_and_revokes_it(
    page, traffic, world, asgi_server, context
) -> None:
    context.grant_permissions(["clipboard-read", "clipboard-write"])
    log_in(page, "customer-a")
    page.get_by_role("navigation", name="Main").get_by_role("link", name="Account").click()
    expect(page).to_have_url(re.compile(r"/accounts/tokens/$"))
    expect(page.get_by_role("link", name="API tokens")).to_have_attribute("aria-current", "page")
    expect(page.locator(".empty")).to_contain_text("No tokens yet")

    page.get_by_label("Name").fill("laptop")
    page.get_by_role("button", name="Make a token").click()
    box = page.locator("#new-token-key")
    expect(box).to_have_value(KEY)
    key = box.input_value()
    expect(box).to_be_focused()
    copy = page.locator("#token-made button[data-copy]")  # its name changes as it copies
    expect(copy).to_have_text("Copy")
    copy.click()
    expect(copy).to_have_text("Copied")
    assert page.evaluate("navigator.clipboard.readText()") == key
    row = page.locator("#tokens tbody tr", has_text="laptop")
    expect(row.locator(".key")).to_have_text(f"{key[:15]}…")
    expect(row.locator(".last-used")).to_have_text("never")

    assert api_status(asgi_server.url, key) == 200
    page.goto("/accounts/tokens/")  # shown once: never again
    expect(page.locator("#new-token-key")).to_have_count(0)
    assert key not in page.content()
    expect(row.locator(".last-used")).to_have_text(re.compile(r"ago$"))

    page.once("dialog", lambda dialog: dialog.accept())  # "Revoke “laptop”? ..."
    row.get_by_role("button", name="Revoke").click()
    expect(page.locator(".messages")).to_contain_text("The token “laptop” is revoked")
    expect(page.locator("#tokens")).to_have_count(0)
    assert api_status(asgi_server.url, key) == 401
