"""``make screenshots``: the README's pictures of the web front end, taken from the real pages.

Runs the demo system (``manage.py demo``: daphne, the embedded Redis, a worker per ground
station and per vehicle) on a free port with a temporary var/ of its own, then drives Debian's
Chromium (/usr/bin/chromium) with Playwright as a customer would: logs in, writes a program in
the editor and submits three copies of it, watches the dashboard, the staff's live map while the
fleet flies, and a finished VV's page. Saves PNGs into docs/screenshots/ and fails if any request
of any page failed or answered 4xx/5xx. Nothing is downloaded (no ``playwright install``).

    .venv/bin/python -m bench.screenshots [--out docs/screenshots] [--speed 10]
"""

from __future__ import annotations

import argparse
import os
import re
import signal
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from playwright.sync_api import BrowserContext, Page, sync_playwright

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM = Path("/usr/bin/chromium")
PASSWORD = "screens-123-pass"
DESKTOP = {"width": 1280, "height": 860}
PHONE = {"width": 390, "height": 844}
START_TIMEOUT_S = 120.0
MISSION_TIMEOUT_S = 240.0

# What the customer types into the editor: a small grid over both operation areas of the
# paper's Figure 3, so that the VV migrates between the two vehicles.
PROGRAM = """\
// A grid survey over both operation areas: CO2 and temperature at every point,
// a GPS fix and a picture at every third one.
var co2 = VV.sensor.get('CO2');
var temp = VV.sensor.get('Thermometer');
var gps = VV.sensor.get('GPS');
var camera = VV.sensor.get('Camera 640x480');

var n = 0;
for (var row = 0; row < 2; ++row) {
  for (var col = 0; col < 5; ++col) {
    var lng = 12.8605 + (row % 2 ? 4 - col : col) * 0.0015;
    var point = new VV.types.LatLngAlt(48.1105 + row * 0.0015, lng, 40);
    var sensors = n % 3 === 0 ? [co2, temp, gps, camera] : [co2, temp];
    var data = VV.task.execute({type: 'point', position: point, tolerance: 3, sensors: sensors});
    VV.storage.store('p' + n + '.co2', data[0]);
    VV.storage.store('p' + n + '.temperature', data[1]);
    if (data.length > 2) {
      VV.storage.store('p' + n + '.gps', data[2]);
      VV.storage.store('p' + n + '.picture', data[3]);
    }
    VV.log('point', n, 'CO2', data[0].value.toFixed(1), 'ppm');
    ++n;
  }
}
VV.storage.store('summary', {points: n, finished: new Date().toISOString()});
"""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Demo:
    """``manage.py demo`` in a process group of its own, on a temporary var/."""

    def __init__(self, var_dir: Path, port: int, speed: float) -> None:
        env = {k: v for k, v in os.environ.items() if k not in ("DATABASE_URL", "REDIS_URL")}
        env |= {
            "CPCC_VAR_DIR": str(var_dir),
            "CPCC_SCENARIO_PASSWORD": PASSWORD,
            "CPCC_ADMIN_PASSWORD": PASSWORD,
            "PYTHONUNBUFFERED": "1",
        }
        self.log_path = var_dir / "demo.log"
        var_dir.mkdir(parents=True, exist_ok=True)
        self.log = self.log_path.open("w")
        self.process = subprocess.Popen(
            [sys.executable, str(ROOT / "manage.py"), "demo", "--speed", str(speed),
             "--port", str(port)],
            cwd=ROOT, env=env, stdout=self.log, stderr=subprocess.STDOUT, start_new_session=True,
        )  # fmt: skip
        self.url = f"http://127.0.0.1:{port}"

    def wait_until_running(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise SystemExit(f"the demo stopped:\n{self.log_path.read_text()[-3000:]}")
            if "CPCC is running at" in self.log_path.read_text():
                return
            time.sleep(0.5)
        raise SystemExit(f"the demo did not start in {START_TIMEOUT_S:.0f} s")

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)  # the demo stops its workers itself
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()
        self.log.close()


class Watch:
    """Every request of a browser context: none may fail or answer 4xx/5xx, no script error."""

    def __init__(self) -> None:
        self.problems: list[str] = []

    def attach(self, context: BrowserContext) -> BrowserContext:
        context.on("requestfailed", lambda r: self.problems.append(f"failed {r.url}: {r.failure}"))
        context.on(
            "response",
            lambda r: self.problems.append(f"{r.status} {r.url}") if r.status >= 400 else None,
        )
        context.on("weberror", lambda e: self.problems.append(f"script error: {e.error}"))
        return context


def wait_for(what: str, check: Callable[[], Any], timeout_s: float) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        value = check()
        if value:
            return value
        time.sleep(0.5)
    raise SystemExit(f"timed out waiting for {what}")


def log_in(page: Page, username: str, then: str) -> None:
    page.goto(f"/accounts/login/?next={then}")
    page.fill("input[name=username]", username)
    page.fill("input[name=password]", PASSWORD)
    with page.expect_navigation():
        page.click("main form [type=submit]")
    if "/accounts/login/" in page.url:
        raise SystemExit(f"{username} could not log in")


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "screenshots")
    parser.add_argument("--speed", type=float, default=10.0, help="the fleet's time acceleration")
    args = parser.parse_args(argv)
    if not CHROMIUM.exists():
        raise SystemExit(f"screenshots need {CHROMIUM} (apt-get install chromium)")
    args.out.mkdir(parents=True, exist_ok=True)
    watch = Watch()
    with tempfile.TemporaryDirectory(prefix="cpcc-screenshots-") as tmp:
        demo = Demo(Path(tmp) / "var", free_port(), args.speed)
        try:
            demo.wait_until_running()
            with sync_playwright() as pw:
                browser = pw.chromium.launch(
                    executable_path=str(CHROMIUM),
                    args=["--no-sandbox", "--disable-gpu", "--disable-background-networking"],
                )
                take(browser, demo.url, args.out, watch)
                browser.close()
        finally:
            demo.stop()
    if watch.problems:
        raise SystemExit("requests that went wrong:\n  " + "\n  ".join(watch.problems))
    print(f"screenshots in {args.out}")


def take(browser: Any, url: str, out: Path, watch: Watch) -> None:
    def context(viewport: dict[str, int]) -> BrowserContext:
        return watch.attach(
            browser.new_context(base_url=url, viewport=viewport, reduced_motion="reduce")
        )

    customer = context(DESKTOP).new_page()
    log_in(customer, "customer-a", then="/vvs/new/")
    customer.fill("input[name=name]", "Grid survey")
    customer.fill("input[name=copies]", "3")
    customer.evaluate("(text) => window.cpccEditor.setValue(text)", PROGRAM)
    customer.click("#check-button")
    wait_for(
        "the syntax check", lambda: customer.get_attribute("#editor-form", "data-check") == "ok", 20
    )
    # The dry run: what it would ask for, on the map of where the platform serves.
    customer.wait_for_selector("#service-map[data-state=ready]")
    customer.click("#dry-run-button")
    wait_for(
        "the dry run",
        lambda: customer.get_attribute("#editor-form", "data-dry-run") == "done",
        120,
    )
    customer.wait_for_selector("#service-map[data-tiles-idle=true]")
    customer.screenshot(path=out / "editor.png", full_page=True)
    with customer.expect_navigation():
        customer.click("#submit-button")

    # The dashboard (where the editor leads), live, while they run.
    customer.wait_for_selector("#dashboard[data-live=true]")
    wait_for(
        "tasks done on the dashboard",
        lambda: (
            customer.locator("tr[data-status=running]").count() >= 2
            and int(customer.locator("td.tasks-done").first.inner_text()) >= 1
        ),
        MISSION_TIMEOUT_S,
    )
    customer.wait_for_timeout(1500)  # past the rows' highlight
    customer.screenshot(path=out / "dashboard.png")

    # The staff's map while the fleet flies them.
    staff = context(DESKTOP).new_page()
    log_in(staff, "admin", then="/map/")
    live = staff.locator("#live-map")
    wait_for(
        "vehicles in flight with tasks done",
        lambda: (
            int(live.get_attribute("data-vehicles") or 0) >= 2
            and int(live.get_attribute("data-tasks-done") or 0) >= 8
        ),
        MISSION_TIMEOUT_S,
    )
    staff.wait_for_selector("#live-map[data-tiles-idle=true]")
    staff.wait_for_timeout(1000)
    staff.screenshot(path=out / "map.png")

    # The operators' live fleet page, while they fly.
    fleet = context(DESKTOP).new_page()
    log_in(fleet, "admin", then="/admin/fleet/vehicle/overview/")
    fleet.wait_for_selector("#fleet-live[data-live=true]")
    fleet.wait_for_timeout(1500)
    fleet.screenshot(path=out / "fleet.png", full_page=True)

    # A finished VV's page: its replay, chart, storage.
    def all_ended() -> bool:
        listed = customer.request.get("/api/v1/vvs/").json()["results"]
        return bool(listed) and all(
            vv["status"] not in ("queued", "running", "migrating") for vv in listed
        )

    wait_for("the VVs to end", all_ended, MISSION_TIMEOUT_S)
    customer.goto("/?show=ended")
    customer.get_by_role("link", name="Grid survey", exact=True).click()
    customer.wait_for_selector("#vv-map[data-replay-to]")
    customer.wait_for_selector("#vv-charts canvas")
    customer.set_viewport_size({"width": 1280, "height": 1350})
    customer.wait_for_timeout(800)
    customer.screenshot(path=out / "vv-page.png")

    phone = context(PHONE).new_page()
    log_in(phone, "customer-a", then="/")
    phone.wait_for_selector("#dashboard[data-live=true]")
    phone.screenshot(path=out / "dashboard-phone.png")
    for page in (customer, staff, fleet, phone):
        if re.search(r"/accounts/login/", page.url):
            raise SystemExit("a page went back to the login form")


if __name__ == "__main__":
    main()
