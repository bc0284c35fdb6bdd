"""Members in Chromium (issue 57): an owner invites a colleague as a viewer on the Members page;
the colleague opens the e-mailed link in a browser of their own, makes their account, lands on
the customer's VVs and reads one without a button to change it; no request fails and no script
errs on the way.

The server runs in a process of its own (tests/browser/conftest.py) with Django's console
e-mail backend (no EMAIL_HOST): the invitation's e-mail is read from the server's output."""

from __future__ import annotations

import os
import re
import time
from pathlib import Path

import pytest
from playwright.sync_api import Page, expect

from accounts.models import User
from accounts.roles import VIEWER
from missions.models import VirtualVehicle, VVStatus
from tests.browser.conftest import Server, World
from tests.browser.pages import log_in
from tests.polling import wait_until

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

COLLEAGUE = "colleague@customer-a.example"
# Where the screenshots of the Members page go (looked at by a person: the layout at a desktop's
# and a phone's width).
SHOTS = Path(os.environ.get("CPCC_SCREENSHOTS", "/tmp"))


def _vv(world: World, customer, name: str) -> VirtualVehicle:
    """A VV that runs at the ground station (one an owner could cancel)."""
    return VirtualVehicle.objects.create(
        customer=customer,
        name=name,
        program="// runs",
        status=VVStatus.RUNNING,
        submitted_s=time.time(),
        seed=1,
        start_ms=0,
        host_gs=world.station,
    )


def mailed_link(server: Server, to: str) -> str:
    """The invitation's link in the newest e-mail to ``to`` that the server printed."""

    def link() -> str | None:
        log = server.log.read_text(errors="replace")
        start = log.rfind(f"To: {to}")
        if start < 0:
            return None
        found = re.search(r"https?://\S+/accounts/invite/[^/\s]+/", log[start:])
        return found[0] if found else None

    wait_until(lambda: link() is not None, timeout=15, what=f"the e-mail to {to}")
    return link() or ""


def shoot(page: Page, width: int) -> None:
    page.set_viewport_size({"width": width, "height": 900})
    page.screenshot(path=str(SHOTS / f"members-{width}.png"), full_page=True)


def test_an_owner_invites_a_colleague_who_reads_the_customers_vvs_read_only(
    page, traffic, new_page, world, asgi_server
) -> None:
    survey = _vv(world, world.customer_a, "Survey")
    _vv(world, world.customer_b, "Bravo's own")

    # The owner invites a colleague as a viewer.
    page.set_viewport_size({"width": 1280, "height": 900})
    log_in(page, "customer-a")
    page.get_by_role("navigation", name="Main").get_by_role("link", name="Account").click()
    page.get_by_role("navigation", name="Account").get_by_role("link", name="Members").click()
    expect(page).to_have_url(re.compile(r"/accounts/members/$"))
    members = page.locator("#members tbody tr")
    expect(members).to_have_count(1)
    expect(members.first).to_contain_text("customer-a")
    form = page.locator("#invite-form")
    form.get_by_label("E-mail").fill(COLLEAGUE)
    form.get_by_label("Role", exact=True).select_option(VIEWER)
    form.get_by_role("button", name="Send the invitation").click()
    expect(page.locator(".messages")).to_contain_text(f"The invitation is sent to {COLLEAGUE}")
    invitation = page.locator("#invites tbody tr", has_text=COLLEAGUE)
    expect(invitation).to_contain_text("viewer")
    expect(
        invitation.get_by_role("button", name=f"Withdraw the invitation to {COLLEAGUE}")
    ).to_be_visible()

    link = mailed_link(asgi_server, COLLEAGUE)
    assert link.startswith(asgi_server.url), link

    # The colleague, in a browser of their own, accepts and lands on the customer's VVs.
    colleague, _ = new_page()
    colleague.goto(link)
    expect(colleague.locator("main")).to_contain_text(f"invites {COLLEAGUE} to join Customer A")
    colleague.get_by_label("User name").fill("colleague")
    colleague.get_by_label("Password").fill("a-long-passphrase")
    colleague.get_by_role("button", name="Accept and make my account").click()
    expect(colleague).to_have_url(re.compile(r"/$"))
    expect(colleague.locator(".messages")).to_contain_text(
        "Welcome to Customer A: you are a viewer."
    )
    rows = colleague.locator("table.vvs tbody tr")
    expect(rows).to_have_count(1)
    expect(rows.first).to_contain_text("Survey")
    assert "Bravo" not in colleague.content()
    expect(rows.first.get_by_role("button")).to_have_count(0)  # no Cancel in its row
    nav = colleague.get_by_role("navigation", name="Main")
    expect(nav.get_by_role("link", name="New VV")).to_have_count(0)
    expect(colleague.get_by_role("link", name="New VV")).to_have_count(0)

    # Its page: everything to read, nothing to change.
    rows.first.get_by_role("link", name="Survey").click()
    expect(colleague).to_have_url(re.compile(rf"/vvs/{survey.pk}/$"))
    expect(colleague.locator("h1")).to_contain_text("Survey")
    actions = colleague.locator(".head-actions")
    for name in ("Cancel", "Edit program", "Restart"):
        expect(colleague.get_by_role("button", name=name)).to_have_count(0)
        expect(colleague.get_by_role("link", name=name)).to_have_count(0)
    expect(actions.get_by_role("link", name="Copy to a new VV")).to_have_count(0)
    expect(colleague.get_by_label(re.compile("^Send a message"))).to_have_count(0)
    expect(colleague.locator("#log")).to_be_visible()

    member = User.objects.get(username="colleague")
    assert (member.customer_id, member.role) == (world.customer_a.pk, VIEWER)

    # The owner's Members page now lists them, and no invitation waits.
    page.reload()
    expect(page.locator("#members tbody tr", has_text="colleague")).to_contain_text(COLLEAGUE)
    expect(page.locator("#invites")).to_have_count(0)
    expect(page.get_by_label("Role of colleague")).to_have_value(VIEWER)
    # One invitation waiting, for the screenshots.
    form.get_by_label("E-mail").fill("another@customer-a.example")
    form.get_by_label("Role", exact=True).select_option("developer")
    form.get_by_role("button", name="Send the invitation").click()
    expect(page.locator("#invites tbody tr")).to_have_count(1)
    shoot(page, 1280)
    shoot(page, 375)
