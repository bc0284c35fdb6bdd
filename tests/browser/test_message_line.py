"""A message from one VV to another shows on the customer's live map as a short-lived dashed
line from the sender to the recipient (static/js/map.js), and never on another customer's.

The screenshot of the map with the line is left in the test's tmp_path (``--basetemp`` to keep
it somewhere known)."""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Any

import pytest
from django.db import transaction
from playwright.sync_api import WebSocket, expect

from missions.events import vv_event
from missions.models import VirtualVehicle, VVStatus
from tests.browser.conftest import World
from tests.browser.pages import log_in
from tests.browser.test_maps import wait_for_tiles
from vvm_worker.live import FeedAnnouncer, publish_vehicle
from vvm_worker.services.messages import message_send

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

HELI_AT = [48.1113, 12.8640]
LINE_MS = 6000  # static/js/map.js: MESSAGE_LINE_MS


def _vv(customer: Any, name: str, **host: Any) -> VirtualVehicle:
    return VirtualVehicle.objects.create(
        customer=customer,
        name=name,
        program="// talks",
        status=VVStatus.RUNNING,
        submitted_s=time.time(),
        seed=1,
        start_ms=0,
        **host,
    )


def test_a_message_between_two_vvs_is_a_dashed_line_for_a_few_seconds_on_their_map_only(
    page, traffic, new_page, world: World, feed, vvm_factory, tmp_path: Path
) -> None:
    vvm = vvm_factory()
    vvm.announcer = FeedAnnouncer(client=feed)
    station = world.station
    scout = _vv(world.customer_a, "Scout", host_rv=world.heli)
    _vv(world.customer_a, "Base", host_gs=station)
    theirs = _vv(world.customer_b, "Theirs", host_gs=station)
    publish_vehicle(
        {
            "id": world.heli.pk,
            "name": world.heli.name,
            "lat": HELI_AT[0],
            "lng": HELI_AT[1],
            "alt": 40.0,
            "phase": "cruise",
            "status": "active",
            "battery": 0.8,
            "vvs": [{"id": str(scout.pk), "name": "Scout", "customer": world.customer_a.pk}],
            "route": [HELI_AT, [48.1125, 12.8660]],
            "t": time.time() + 60,  # still fresh when the pages ask, however slow the machine
        },
        client=feed,
    )

    log_in(page, "customer-a", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    expect(live).to_have_attribute("data-vehicles", "1")
    expect(live).to_have_attribute("data-messages-shown", "0")
    page_b, _ = new_page()
    frames_b: list[str] = []

    def watch(socket: WebSocket) -> None:
        socket.on("framereceived", lambda payload: frames_b.append(str(payload)))

    page_b.on("websocket", watch)
    log_in(page_b, "customer-b", then="/map/")
    live_b = page_b.locator("#live-map")
    expect(live_b).to_have_attribute("data-connected", "true")
    expect(live_b).to_have_attribute("data-vvs", "1")
    wait_for_tiles(page, "#live-map")

    with transaction.atomic():  # as a VV's step sends it: announced once it commits
        message_send(
            customer_id=world.customer_a.pk, sender=scout, to="Base", value_json="3", vvm=vvm
        )

    # Scout (aboard Heli One) to Base (on GS Base): one dashed line, not a migration's colour.
    expect(live).to_have_attribute("data-messages-shown", "1")
    expect(live).to_have_attribute("data-messages", "1")
    line = page.evaluate(
        """() => {
          const shown = window.cpccMap.messageLines[0];
          const ends = shown.line.getLatLngs().map((p) => [p.lat, p.lng]);
          return {ends, at: shown.at, dash: shown.line.options.dashArray,
                  color: shown.line.options.color,
                  says: shown.line.getTooltip().getContent().textContent};
        }"""
    )
    assert line["ends"] == [HELI_AT, [station.lat, station.lng]]
    assert line["dash"] and line["color"] not in ("#d62828", "#2a9d3a", "#7ec8f5", "#1f6fe5")
    assert line["says"] == "Scout → Base: a message"
    page.screenshot(path=tmp_path / "msg_line.png")

    # Gone after a few seconds, by itself.
    page.wait_for_function(
        "() => document.getElementById('live-map').dataset.messagesShown === '0'",
        timeout=LINE_MS * 3,
    )
    shown_ms = page.evaluate("() => Date.now()") - line["at"]
    assert LINE_MS <= shown_ms < LINE_MS * 2, f"the line was shown {shown_ms} ms"
    assert page.evaluate("() => window.cpccMap.layers.messages.getLayers().length") == 0

    # Customer B's map got a change of its own VV after the message, and never the message.
    with transaction.atomic():
        theirs.status = VVStatus.CANCELLED
        theirs.save()
        vvm.announce_at_commit(lambda: vv_event(theirs))
    page_b.wait_for_function(
        "(id) => (window.cpccMap.vvs[id] || {}).status === 'cancelled'", arg=str(theirs.pk)
    )
    assert frames_b, "B's socket got its snapshot and frames"
    received = [json.loads(f) for f in frames_b]
    events = [e for f in received for e in f.get("events", ())]
    assert [e["kind"] for e in events if e["kind"] == "message"] == []
    assert "Scout" not in str(received) and str(scout.pk) not in str(received)
    assert live_b.get_attribute("data-messages") == "0"
