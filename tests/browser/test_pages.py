"""The pages anyone reaches first: the login forms and the API docs, served whole by the
platform (styles, scripts, fonts, icons) with nothing from the internet."""

from __future__ import annotations

import re

import pytest
from playwright.sync_api import expect

# The server reads the test database, which pytest-django creates only for tests that ask.
pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)


def test_the_login_form_refuses_a_wrong_password(page, traffic) -> None:
    page.goto("/map/")
    assert "/accounts/login/" in page.url, "the map is for logged-in users"
    page.locator("input[name=username]").fill("nobody")
    page.locator("input[name=password]").fill("not-the-password")
    page.locator("main form [type=submit]").click()
    expect(page.locator("main")).to_contain_text("didn't match")
    expect(page.locator("input[name=username]")).to_have_value("nobody")


def test_the_admin_login_is_styled(page, traffic) -> None:
    page.goto("/admin/")
    expect(page).to_have_url(re.compile(r"/admin/login/\?next=/admin/$"))
    expect(page.locator("#site-name")).to_have_text("CPCC administration")
    # The admin's stylesheet is there: the header has its colour, not the browser's default.
    header = page.locator("#header").evaluate("e => getComputedStyle(e).backgroundColor")
    assert header not in ("rgba(0, 0, 0, 0)", "transparent"), header


def test_the_api_docs_render_offline(page, traffic) -> None:
    page.goto("/api/docs/")
    expect(page.locator(".swagger-ui .info .title")).to_contain_text("CPCC API")
    expect(page.locator("#operations-tag-vvs")).to_be_visible()

    page.goto("/api/redoc/")
    expect(page.get_by_role("heading", name=re.compile(r"^CPCC API"), level=1)).to_be_visible()
    expect(page.get_by_role("menuitem", name=re.compile(r"^vvs$"))).to_be_visible()
