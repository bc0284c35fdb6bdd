"""A customer's VV flies on the real platform (daphne, a GS worker, an RV worker) and the
customer watches it in the browser; another customer sees none of it; staff see it all."""

from __future__ import annotations

import json
import re
import zipfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest
from playwright.sync_api import Error as PlaywrightError
from playwright.sync_api import Page, expect

from missions.models import VirtualVehicle, VVStatus
from tests.browser.pages import log_in, map_state
from tests.conftest import PROGRAMS
from tests.live import Workers
from tests.polling import wait_until
from vvm_worker.runtime import check_syntax

pytestmark = [pytest.mark.django_db(transaction=True, serialized_rollback=True), pytest.mark.slow]

VV1 = (PROGRAMS / "vv1-paper.js").read_text()
# VV 1 with a parenthesis missing on line 4 (`VV.sensor.get('Thermometer';`).
VV1_BROKEN = VV1.replace("get('Thermometer');", "get('Thermometer';", 1)
# What the platform's check says of it (computed here: V8 refuses to run once Playwright's loop
# runs in this thread).
PROBLEM = check_syntax(VV1_BROKEN)
KEYS = sorted(f"p{n}.{k}" for n in range(4) for k in range(3))  # what VV 1 stores
SOME = re.compile(r"^[1-9][0-9]*$")
FLIGHT_MS = 90_000  # VV 1's four points take about 15 s at the tests' speed


@contextmanager
def explained(workers: Workers) -> Iterator[None]:
    """A failure also says what the workers and the VVs were doing."""
    try:
        yield
    except (AssertionError, PlaywrightError) as exc:
        errors = list(VirtualVehicle.objects.values_list("name", "status", "error"))
        raise AssertionError(f"{exc}\n{workers.logs()}\nVVs: {errors}") from exc


def write_and_submit(page: Page, name: str) -> str:
    """In the program editor: VV 1 written with a syntax error, which the check shows with
    its line and column; the error fixed in the editor; the program submitted. The new VV's
    id, from its row on the dashboard."""
    page.get_by_role("navigation", name="Main").get_by_role("link", name="New VV").click()
    form = page.locator("#editor-form")
    page.get_by_label("Name").fill(name)
    page.locator(".CodeMirror").click()
    page.keyboard.insert_text(VV1_BROKEN)
    assert page.evaluate("window.cpccEditor.getValue()") == VV1_BROKEN

    page.get_by_role("button", name="Check").click()
    expect(form).to_have_attribute("data-check", "error")
    assert PROBLEM is not None and PROBLEM.line == 4
    expect(page.get_by_role("status")).to_have_text(
        f"Line 4, column {PROBLEM.column}: {PROBLEM.message}"
    )

    # Where the editor marks the error, on line 4: the parenthesis goes before the semicolon.
    page.locator(".CodeMirror .cm-error-mark").click()
    page.keyboard.press("End")
    page.keyboard.press("ArrowLeft")
    page.keyboard.type(")")
    assert page.evaluate("window.cpccEditor.getValue()") == VV1
    page.get_by_role("button", name="Check").click()
    expect(form).to_have_attribute("data-check", "ok")

    page.get_by_role("button", name="Submit").click()
    # Submitting one VV opens its page; then on to the dashboard, where its row is.
    page.wait_for_url(re.compile(r"/vvs/[0-9a-f-]{36}/$"))
    expect(page.locator(".messages")).to_contain_text(f"“{name}” is submitted.")
    vv_id = page.url.rstrip("/").rsplit("/", 1)[1]
    one_state_from_the_first_paint(page)
    page.get_by_role("navigation", name="Main").get_by_role("link", name="Dashboard").click()
    row = page.locator("tr[data-vv]", has=page.get_by_role("link", name=name, exact=True))
    assert row.get_attribute("data-vv") == vv_id
    # A form sends a textarea's lines ending in CR LF (the HTML standard): the same program.
    assert VirtualVehicle.objects.get(pk=vv_id).program.replace("\r\n", "\n") == VV1
    return vv_id


# What the VV's page says of the VV in its parts: the status badge, where it is, whether it
# offers "Edit program", the waiting banner, its tasks-open figure and the live map's.
PAGE_STATE = """() => {
  const edit = document.querySelector('.head-actions a[href$="/edit/"]');
  const waiting = document.getElementById('vv-waiting');
  const map = document.getElementById('vv-map');
  return {
    status: document.getElementById('vv-status').className.replace(/.*status-(\\w+).*/, '$1'),
    where: document.getElementById('vv-where').textContent,
    edit: !!edit && !edit.hidden,
    waiting: waiting.hidden ? '' : waiting.dataset.reason || 'shown',
    open: document.getElementById('vv-tasks-open').textContent,
    map_open: map.dataset.tasksOpen || null,
  };
}"""


def one_state_from_the_first_paint(page: Page) -> None:
    """Right after Submit, the VV's page never says two things at once: queued (where
    "queued", "Edit program" offered, waiting in the queue) or started (neither), whichever
    part is looked at, while it starts; once the live map counts its tasks, the page's figure
    follows within a poll."""
    seen = []
    for _ in range(40):
        state = page.evaluate(PAGE_STATE)
        seen.append(state)
        queued = state["status"] == "queued"
        assert state["edit"] == queued, seen
        assert (state["where"] == "queued") == queued, seen
        assert queued or state["waiting"] != "queue", seen
        if not queued and state["map_open"] not in (None, state["open"]):
            break  # the map counts before the page has read: the page reads at once
        page.wait_for_timeout(100)
    page.wait_for_function(
        f"() => {{ const s = ({PAGE_STATE})(); return s.map_open === null || s.map_open === s.open; }}",
        timeout=10_000,
    )


def carrier(page) -> dict:
    """The one vehicle on the map, once there is one."""
    page.wait_for_function("() => Object.keys(window.cpccMap.vehicles).length === 1")
    (vehicle,) = map_state(page)["vehicles"]
    return vehicle


def test_a_customer_writes_vv1_watches_it_fly_and_gets_its_results_others_see_nothing(
    page, traffic, new_page, world, workers
) -> None:
    with explained(workers):
        workers.start("gsworker", "GS Base")
        workers.start("rvworker", "Heli One")
        # Staff watch the whole fleet's map from the start (VV 1 may be aboard for seconds).
        page_staff, _ = new_page()
        log_in(page_staff, "operator", then="/map/")
        log_in(page, "customer-a")
        vv_id = write_and_submit(page, "VV 1")
        dashboard = page
        # The live map in a second tab: the dashboard stays open and must follow by itself.
        with page.context.expect_page() as opened:
            page.get_by_role("link", name="Map", exact=True).click(modifiers=["Control"])
        page = opened.value
        live = page.locator("#live-map")
        expect(live).to_have_attribute("data-connected", "true")
        expect(live).to_have_attribute("data-vvs", "1")
        # Its first task appears (a blue dot) and a vehicle picks it up...
        expect(live).to_have_attribute("data-tasks-open", SOME, timeout=FLIGHT_MS)
        first = carrier(page)
        assert first["vvs"] == [{"id": vv_id, "name": "VV 1", "customer": world.customer_a.pk}]
        # ...anonymous to the customer: no name, no route (it would show others' tasks).
        assert "name" not in first and "route" not in first
        # Staff see the vehicle by its name, with VV 1 aboard.
        page_staff.wait_for_function(
            """() => Object.values(window.cpccMap.vehicles).some((v) =>
                 v.name === 'Heli One' && v.vvs.some((vv) => vv.name === 'VV 1'))""",
            timeout=FLIGHT_MS,
        )
        # The marker moves: another frame puts the vehicle somewhere else, and the marker is
        # drawn there (on the next animation frame).
        page.wait_for_function(
            """([lat, lng]) => Object.entries(window.cpccMap.vehicles).some(([id, v]) => {
                 const marker = window.cpccMap.vehicleMarkers[id];
                 if (!marker || (v.lat === lat && v.lng === lng)) return false;
                 const drawn = marker.getLatLng();
                 return drawn.lat === v.lat && drawn.lng === v.lng;
               })""",
            arg=[first["lat"], first["lng"]],
            timeout=FLIGHT_MS,
        )
        moved = carrier(page)
        assert moved["marker"] != first["marker"]
        assert int(live.get_attribute("data-seq") or 0) > 1

        # Customer B, meanwhile: its map stays empty while A's tasks turn red.
        page_b, traffic_b = new_page()
        log_in(page_b, "customer-b", then="/map/")
        live_b = page_b.locator("#live-map")
        expect(live_b).to_have_attribute("data-connected", "true")
        done_before = live.get_attribute("data-tasks-done")
        expect(live).not_to_have_attribute("data-tasks-done", done_before or "", timeout=FLIGHT_MS)
        state_b = map_state(page_b)
        assert (state_b["vvs"], state_b["vehicles"], state_b["vvNames"]) == ("0", [], [])
        assert (state_b["tasksOpen"], state_b["tasksDone"]) == ("0", "0")

        # All four tasks done (red), nothing open; the carrier leaves the customer's map. (The
        # map shows the running VVs by default: VV 1 stays on it, once ended, with every one.)
        page.get_by_label("Virtual vehicles").select_option(label="every one")
        expect(live).to_have_attribute("data-tasks-done", "4", timeout=FLIGHT_MS)
        expect(live).to_have_attribute("data-tasks-open", "0")
        expect(live).to_have_attribute("data-vehicles", "0")
        assert "Heli One" not in page.content()
        wait_until(
            lambda: VirtualVehicle.objects.get(pk=vv_id).status == VVStatus.FINISHED,
            timeout=30,
            what="VV 1 to finish",
        )

        see_the_results(dashboard, vv_id)

        # B's pages show nothing of it, and A's VV is not found for B.
        page_b.get_by_role("link", name="Dashboard").click()
        expect(page_b.locator("tr[data-vv]")).to_have_count(0)
        page_b.get_by_role("link", name="Map", exact=True).click()
        expect(page_b.locator("#live-map")).to_have_attribute("data-connected", "true")
        expect(page_b.locator("#live-map")).to_have_attribute("data-vvs", "0")
        for shown in (page_b.locator("#live-map"), page_b.locator("main")):
            expect(shown).not_to_contain_text("VV 1")
            expect(shown).not_to_contain_text("Heli One")
        traffic_b.expect(404, f"/vvs/{vv_id}/")
        response = page_b.goto(f"/vvs/{vv_id}/")
        assert response is not None and response.status == 404
        expect(page_b.locator("body")).not_to_contain_text("VV 1")


def see_the_results(page: Page, vv_id: str) -> None:
    """On the dashboard, open since the VV was submitted: VV 1 finished with its four tasks,
    without a reload. On its page: its mission replayed on its map, a camera picture opened
    full size, the results downloaded."""
    row = page.locator(f'tr[data-vv="{vv_id}"]')
    expect(row).to_have_attribute("data-status", "finished")
    expect(row.locator(".tasks-done")).to_have_text("4")
    expect(page.locator("#dashboard")).to_have_attribute("data-live", "true")
    expect(page.locator("#dashboard")).not_to_have_attribute("data-refreshes", "0")
    row.get_by_role("link", name="VV 1").click()
    expect(page.locator("#vv-status")).to_have_text("Finished")

    # The replay: every task done at the end of the mission, none at its start.
    vv_map = page.locator("#vv-map")
    expect(page.locator("#replay")).to_be_visible()
    expect(vv_map).to_have_attribute("data-tasks-done", "4")
    page.get_by_label("Time in the mission").fill("0")
    expect(vv_map).to_have_attribute("data-tasks-done", "0")
    page.get_by_label("Time in the mission").fill("1000")
    expect(vv_map).to_have_attribute("data-tasks-done", "4")

    # A camera reading's thumbnail (p3.2: the picture of the fourth point) opens full size.
    thumbnail = page.get_by_role("link", name="picture of Camera 640x480 (p3.2)", exact=True)
    thumbnail.scroll_into_view_if_needed()
    expect(thumbnail.locator("img")).to_have_js_property("complete", True)
    assert thumbnail.locator("img").evaluate("img => img.naturalWidth") == 640
    with page.expect_navigation() as opened:
        thumbnail.click()
    response = opened.value
    assert response is not None and response.status == 200
    assert response.headers["content-type"] == "image/png"
    assert page.evaluate("[document.images[0].naturalWidth, document.images[0].naturalHeight]") == [
        640,
        480,
    ]
    page.go_back()

    # The downloads: the results as a zip, the storage as JSON.
    with page.expect_download() as got:
        page.get_by_role("link", name="results.zip").click()
    with zipfile.ZipFile(got.value.path()) as results:
        names = results.namelist()
        vv = json.loads(results.read("vv.json"))
        storage = json.loads(results.read("storage.json"))
    assert "vv.json" in names and "tasks.json" in names and "log.txt" in names
    assert sum(name.startswith("images/") for name in names) == 4
    assert (vv["name"], vv["status"]) == ("VV 1", "finished")
    assert sorted(storage) == KEYS
    with page.expect_download() as got:
        page.get_by_role("link", name="storage.json").click()
    assert sorted(json.loads(Path(got.value.path()).read_text())) == KEYS


def test_the_live_map_keeps_what_ended_when_an_older_word_arrives_late(world, page) -> None:
    """Each worker publishes its changes in its own order: the word that a task was served
    or a VV finished may reach the map before an older word about it, which changes nothing."""
    log_in(page, "customer-a", then="/map/")
    live = page.locator("#live-map")
    expect(live).to_have_attribute("data-connected", "true")
    # Every VV, the ended too, and all the map holds (these words are of long ago).
    page.get_by_label("Virtual vehicles").select_option(label="every one")
    page.get_by_label("History").select_option(label="all the map holds")
    vv = "00000000-0000-4000-8000-000000000001"
    task = {"kind": "task", "vv": vv, "id": 7, "q": 0, "index": 0, "lat": 48.11, "lng": 12.87,
            "alt": 10.0, "requested_s": 1.0}  # fmt: skip
    done = {**task, "status": "done", "done_s": 2.0}
    opened = {**task, "status": "open", "done_s": None}
    finished = {"kind": "vv", "vv": vv, "name": "VV", "status": "finished", "host_kind": "gs",
                "host": "GS Base"}  # fmt: skip
    running = {**finished, "status": "running", "host_kind": "rv", "host": "Heli One"}
    page.evaluate(
        "(events) => window.cpccMap.applyFrame({seq: window.cpccMap.seq, events: events})",
        [done, finished, opened, running],
    )
    expect(live).to_have_attribute("data-tasks-open", "0")
    expect(live).to_have_attribute("data-tasks-done", "1")
    assert page.evaluate(f"() => window.cpccMap.vvs['{vv}'].status") == "finished"
