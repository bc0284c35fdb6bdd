"""``python -m bench.map_browser``: the live map in a real browser with 1,000 RVs drawn.

Starts the web server (daphne, the project's ASGI application) on a fresh SQLite database and
Redis (the embedded server, or ``--redis``), logs a staff user in through the login form in
Debian's Chromium (/usr/bin/chromium, headless, driven by Playwright) and opens the live map
(/map/). It then detaches the page's socket and feeds the map synthetic frames in the page,
``--hz`` times a second, through ``window.cpccMap.applyFrame`` (static/js/map.js): ``--rvs``
vehicles in the shape of missions/events.py's vehicle states, each moving a little and with a
planned route of three points, the way the staff map sees a large fleet. Over ``--seconds``
it measures in the browser:

- the frame time: the intervals between animation frames (``requestAnimationFrame``), p50,
  p99 and max, and how many exceeded 50 ms (a visible stutter); the same for the frames that
  draw and paint an update (the two after each ``applyFrame``);
- per update: the time spent in ``applyFrame`` (the frame's data), in the map's draw (the
  layers updated on the next animation frame) and in Leaflet's canvas redraw, p50 and p99;
- the first frame (every marker created) on its own.
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
ASGI_APP = "cpcc_site.asgi:application"
CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
]
USER, PASSWORD = "bench-staff", "bench-pass-123"

# Runs in the page: feeds the map and measures. Returns the raw timings (ms).
MEASURE = """
async ({rvs, hz, seconds}) => {
  const map = window.cpccMap;
  if (map.socket) {            // only the synthetic frames below reach the map
    map.socket.onclose = null;
    map.socket.onmessage = null;
    map.socket.close();
  }
  const timings = {draw: [], redraw: [], apply: [], gaps: [], updateGaps: []};
  const timed = (owner, name, into) => {
    const original = owner[name];
    owner[name] = function () {
      const t0 = performance.now();
      const result = original.apply(this, arguments);
      into.push(performance.now() - t0);
      return result;
    };
  };
  timed(map, '_draw', timings.draw);
  // An update is drawn on the animation frame after applyFrame and painted by Leaflet's canvas
  // on the one after that: those two frames are the update's frames.
  let updateFrames = 0;
  const draw = map._draw;
  map._draw = function () { updateFrames = 2; return draw.apply(this, arguments); };
  timed(map.renderer, '_redraw', timings.redraw);

  const states = (k) => {
    const t = Date.now() / 1000;
    const out = new Array(rvs);
    for (let i = 0; i < rvs; i++) {
      const row = Math.floor(i / 40), col = i % 40;
      const lat = 48.100 + row * 0.0004 + 0.00012 * Math.sin((k + i) / 7);
      const lng = 12.850 + col * 0.0006 + 0.00012 * Math.cos((k + i) / 7);
      out[i] = {
        id: i + 1, name: 'RV ' + (i + 1), lat: lat, lng: lng, alt: 50, phase: 'cruise',
        status: 'active', vvs: [],
        route: [[lat, lng], [lat + 0.0003, lng + 0.0002], [lat + 0.0001, lng + 0.0005]], t: t
      };
    }
    return out;
  };
  const nextFrame = () => new Promise((resolve) => requestAnimationFrame(() => resolve()));
  let seq = map.seq;
  let k = 0;

  // The first frame creates every marker: measured on its own.
  let t0 = performance.now();
  map.applyFrame({seq: ++seq, events: [], vehicles: states(k++), gone: []});
  const firstApply = performance.now() - t0;
  await nextFrame(); await nextFrame();
  const first = {apply: firstApply, draw: timings.draw.slice(), redraw: timings.redraw.slice()};
  const lats = Object.values(map.vehicles).map((v) => [v.lat, v.lng]);
  map.map.fitBounds(L.latLngBounds(lats).pad(0.05), {animate: false});
  await nextFrame(); await nextFrame();
  timings.draw.length = 0; timings.redraw.length = 0;

  let running = true, last = null;
  const tick = (now) => {
    if (last !== null) {
      timings.gaps.push(now - last);
      if (updateFrames > 0) { timings.updateGaps.push(now - last); updateFrames -= 1; }
    }
    last = now;
    if (running) requestAnimationFrame(tick);
  };
  requestAnimationFrame(tick);
  await new Promise((resolve) => {
    const end = performance.now() + seconds * 1000;
    const feed = setInterval(() => {
      if (performance.now() >= end) { clearInterval(feed); resolve(); return; }
      const frame = {seq: ++seq, events: [], vehicles: states(k++), gone: []};
      const t1 = performance.now();
      map.applyFrame(frame);
      timings.apply.push(performance.now() - t1);
    }, 1000 / hz);
  });
  await nextFrame(); await nextFrame();
  running = false;
  return {
    first: first, timings: timings, updates: k - 1,
    drawn: Number(document.getElementById('live-map').dataset.vehicles),
    markers: Object.keys(map.vehicleMarkers).length
  };
}
"""


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _pct(values: list[float], p: int) -> float:
    if len(values) < 2:
        return values[0] if values else float("nan")
    return statistics.quantiles(values, n=100, method="inclusive")[p - 1]


def _line(name: str, values: list[float]) -> str:
    return (
        f"{name}: p50 {statistics.median(values):.1f} ms  p99 {_pct(values, 99):.1f} ms  "
        f"max {max(values):.1f} ms  (n={len(values)})"
    )


def _setup_database() -> None:
    import django

    django.setup()
    from django.core.management import call_command

    from accounts.models import User

    call_command("migrate", verbosity=0)
    User.objects.create_user(USER, password=PASSWORD, is_staff=True)


def _measure(url: str, rvs: int, hz: float, seconds: float) -> tuple[dict[str, Any], str]:
    from playwright.sync_api import sync_playwright

    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, headless=True, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{url}/accounts/login/?next=/map/")
        page.locator("input[name=username]").fill(USER)
        page.locator("input[name=password]").fill(PASSWORD)
        with page.expect_navigation():
            page.locator("main form [type=submit]").first.click()
        page.wait_for_selector("#live-map[data-connected=true]")
        result = page.evaluate(MEASURE, {"rvs": rvs, "hz": hz, "seconds": seconds})
        version = browser.version
        browser.close()
    return result, version


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--rvs", type=int, default=1000)
    parser.add_argument("--hz", type=float, default=2.0)
    parser.add_argument("--seconds", type=float, default=20.0)
    parser.add_argument("--redis", default="", help="redis:// URL (default: embedded)")
    args = parser.parse_args()
    if not Path(CHROMIUM).exists():
        sys.exit(f"no {CHROMIUM}: apt-get install chromium")

    tmp = Path(tempfile.mkdtemp(prefix="cpcc-bench-browser-"))
    env = {
        **os.environ,
        "DJANGO_SETTINGS_MODULE": "cpcc_site.settings",
        "DATABASE_URL": f"sqlite:///{tmp / 'db.sqlite3'}",
        "CPCC_VAR_DIR": str(tmp),
        "DEBUG": "1",  # static files from the apps' folders, as in the demo
    }
    embedded = None
    if args.redis:
        env["REDIS_URL"] = args.redis
    else:
        from cpcc_site.embedded_redis import EmbeddedRedis

        sock = tmp / "redis.sock"
        embedded = EmbeddedRedis(sock)
        embedded.start()
        env["REDIS_URL"] = f"unix://{sock}"
    os.environ.update(env)
    sys.path.insert(0, str(ROOT))
    _setup_database()

    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    web = subprocess.Popen(
        [sys.executable, "-m", "daphne", "-b", "127.0.0.1", "-p", str(port), ASGI_APP],
        cwd=ROOT,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.time() + 30
        while True:
            try:
                with urllib.request.urlopen(f"{url}/accounts/login/", timeout=2):
                    break
            except OSError:
                if time.time() > deadline or web.poll() is not None:
                    sys.exit("the web server did not start")
                time.sleep(0.1)
        result, version = _measure(url, args.rvs, args.hz, args.seconds)
    finally:
        web.terminate()
        try:
            web.wait(10)
        except subprocess.TimeoutExpired:
            web.kill()
            web.wait()
        if embedded is not None:
            embedded.stop()

    timings = result["timings"]
    gaps = timings["gaps"]
    # One draw and one canvas redraw follow each update (on the next animation frame).
    per_update = [a + d for a, d in zip(timings["apply"], timings["draw"], strict=False)]
    with_paint = [u + r for u, r in zip(per_update, timings["redraw"], strict=False)]
    first = result["first"]
    print(
        f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; "
        f"Chromium {version} headless, software rendering"
    )
    print(
        f"{args.rvs} RVs drawn ({result['markers']} markers, the map says {result['drawn']}), "
        f"{result['updates']} updates at {args.hz:g} Hz over {args.seconds:g} s"
    )
    print(
        f"first frame (every marker created): applyFrame {first['apply']:.1f} ms, "
        f"draw {sum(first['draw']):.1f} ms, canvas redraw {sum(first['redraw']):.1f} ms"
    )
    print(_line("frame time (requestAnimationFrame intervals)", gaps))
    print(f"  frames over 50 ms: {sum(1 for g in gaps if g > 50)} of {len(gaps)}")
    print(_line("  the two frames of each update", timings["updateGaps"]))
    print(_line("applyFrame", timings["apply"]))
    print(_line("draw (layers updated)", timings["draw"]))
    print(_line("canvas redraw (Leaflet)", timings["redraw"]))
    print(_line("applyFrame + draw, per update", per_update))
    print(_line("applyFrame + draw + canvas redraw, per update", with_paint))


if __name__ == "__main__":
    main()
