"""``manage.py demo``: the whole local system runs and stops cleanly."""

from __future__ import annotations

import json
import os
import queue
import re
import signal
import socket
import stat
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path

import pytest

from cpcc_site.embedded_redis import answers
from tests.polling import wait_until

ROOT = Path(__file__).resolve().parents[2]


def processes_of(var_dir: Path) -> list[int]:
    """The processes still running with this demo's CPCC_VAR_DIR in their environment."""
    mark = f"CPCC_VAR_DIR={var_dir}".encode()
    found = []
    for proc in Path("/proc").iterdir():
        if proc.name.isdigit() and int(proc.name) != os.getpid():
            try:
                if mark in (proc / "environ").read_bytes().split(b"\0"):
                    found.append(int(proc.name))
            except OSError:
                continue
    return found


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run_demo(tmp_path: Path, *args: str, interrupts: int = 1) -> tuple[str, int]:
    """Run ``manage.py demo ARGS`` until its scenario has ended, then Ctrl-C it (``interrupts``
    times, as an impatient user does); returns its output and port, after checking that it
    stopped cleanly and left nothing running, and that its terminal stayed readable: no line
    for each request, no warning that the workers run as root (when they do)."""
    port = free_port()
    env = {
        **os.environ,
        "CPCC_VAR_DIR": str(tmp_path),
        "DATABASE_URL": f"sqlite:///{tmp_path / 'db.sqlite3'}",
        "CPCC_SCENARIO_PASSWORD": "demo-pass-123",
    }
    env.pop("REDIS_URL", None)  # the demo's own embedded Redis
    demo = subprocess.Popen(
        [sys.executable, "manage.py", "demo", *args, "--port", str(port)],
        cwd=ROOT,
        env=env,
        stdin=subprocess.DEVNULL,  # not the terminal pytest may run in
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    lines: list[str] = []
    try:
        assert demo.stdout is not None
        output_lines: queue.Queue[str] = queue.Queue()
        reader = threading.Thread(
            target=lambda: [output_lines.put(x) for x in demo.stdout], daemon=True
        )
        reader.start()
        deadline = time.monotonic() + 150
        while not lines or "The scenario has ended" not in lines[-1]:
            try:
                lines.append(output_lines.get(timeout=max(0.0, deadline - time.monotonic())))
            except queue.Empty:
                raise AssertionError(
                    "the demo did not finish the scenario:\n" + "".join(lines)
                ) from None
            assert demo.poll() is None, "the demo exited early:\n" + "".join(lines)
        output = "".join(lines)
        assert answers(tmp_path / "redis" / "redis.sock")
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/accounts/login/", timeout=10) as page:
            assert page.status == 200
            login_page = page.read().decode()
        served_as_in_production(f"http://127.0.0.1:{port}", login_page)
    finally:
        demo.send_signal(signal.SIGINT)
        if interrupts > 1:
            while "Stopping" not in lines[-1] and demo.poll() is None:
                lines.append(output_lines.get(timeout=30))
            demo.send_signal(signal.SIGINT)
        demo.wait(timeout=60)
    reader.join(timeout=10)  # the lines its processes wrote last, up to the pipe's end
    while not output_lines.empty():
        lines.append(output_lines.get())
    output = "".join(lines)
    assert demo.returncode == 0, output
    if interrupts == 1:  # every process it started stopped by itself, with status 0
        assert "exit status" not in output and "killed" not in output, output
    assert not answers(tmp_path / "redis" / "redis.sock")
    assert processes_of(tmp_path) == [], "the demo left processes behind"
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0  # the web server is gone too
    # It fetched pages and a stylesheet (served_as_in_production): the errors show, the
    # requests do not (daphne's access log: '127.0.0.1:PORT - - [DATE] "GET /PATH" 200 SIZE').
    assert "Not Found: /no-such-page/" in output
    assert '"GET /' not in output, output
    assert "SecurityWarning" not in output and "superuser privileges" not in output, output
    return output, port


def served_as_in_production(url: str, login_page: str) -> None:
    """DEBUG off: the site's own 404 page (not Django's debug page listing every URL), JSON
    under /api/, the static files collected under hashed names and served."""
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(f"{url}/no-such-page/", timeout=10)
    page = missing.value.read().decode()
    assert missing.value.code == 404
    assert "Not found" in page and "URLconf" not in page
    with pytest.raises(urllib.error.HTTPError) as missing:
        urllib.request.urlopen(f"{url}/api/v1/no-such-thing/", timeout=10)
    assert missing.value.code == 404
    assert json.loads(missing.value.read())["detail"].startswith("No API endpoint")
    stylesheet = re.search(r'href="(/static/css/cpcc\.[0-9a-f]{12}\.css)"', login_page)
    assert stylesheet, login_page
    with urllib.request.urlopen(url + stylesheet[1], timeout=10) as css:
        assert css.status == 200


def test_demo_serves_the_web_pages_runs_the_scenario_and_stops_on_ctrl_c(tmp_path: Path) -> None:
    output, port = run_demo(tmp_path, "--speed", "0")
    assert f"CPCC is running at http://127.0.0.1:{port}/" in output
    assert "customer: customer-a / demo-pass-123" in output
    # Next to the paper's Figure 3, on the same fleet, the examples of messages and pictures
    # for a customer of their own (examples/scenarios/messages-and-images.json).
    assert "customer: customer-d / demo-pass-123" in output
    assert "VVs ended 6/6" in output
    assert "with 1 ground-station and 2 vehicle worker(s)" in output
    assert "VV 1 (Customer A): finished" in output
    for name in ("survey-west", "survey-east", "vegetation"):
        assert f"{name} (Customer D): finished" in output
    # Where to log in, also in a file only this user can read, its path printed with them.
    logins = tmp_path / "demo-logins.txt"
    assert f"(these logins are kept in {logins})" in output
    assert stat.S_IMODE(logins.stat().st_mode) == 0o600
    kept = logins.read_text().splitlines()
    admin = re.search(r"^  admin: admin / \S+ .*$", output, re.MULTILINE)
    assert admin
    assert kept == [
        f"CPCC is running at http://127.0.0.1:{port}/",
        admin[0],
        *(f"  customer: customer-{x} / demo-pass-123" for x in "abcd"),
        # To try the roles (issue 57): a viewer of the first customer, a pilot of every RV.
        "  viewer: customer-a-viewer / demo-pass-123  (Customer A, read only)",
        "  pilot: pilot / demo-pass-123  (staff, may fly Heli One, Heli Two; not on duty)",
    ]
    import sqlite3

    with sqlite3.connect(tmp_path / "db.sqlite3") as db:
        viewer = db.execute(
            "SELECT u.role, c.name FROM accounts_user u JOIN accounts_customer c"
            " ON u.customer_id = c.id WHERE u.username = 'customer-a-viewer'"
        ).fetchall()
        pilot = db.execute(
            "SELECT u.is_staff, u.is_superuser, g.name FROM accounts_user u"
            " JOIN accounts_user_groups ug ON ug.user_id = u.id JOIN auth_group g"
            " ON g.id = ug.group_id WHERE u.username = 'pilot'"
        ).fetchall()
        flown = db.execute(
            "SELECT v.name, v.pilot_on_duty_id FROM fleet_vehicle v JOIN fleet_vehicle_pilots p"
            " ON p.vehicle_id = v.id JOIN accounts_user u ON u.id = p.user_id"
            " WHERE u.username = 'pilot' ORDER BY v.name"
        ).fetchall()
    assert viewer == [("viewer", "Customer A")]
    assert pilot == [(1, 0, "pilot")]
    assert flown == [("Heli One", None), ("Heli Two", None)]


def test_demo_flies_the_papers_figure_3_over_mavlink(tmp_path: Path) -> None:
    output, _ = run_demo(
        tmp_path,
        "--scenario",
        "examples/scenarios/paper-fig3.json",  # the paper's alone
        "--speed",
        "40",
        "--mavlink",
        interrupts=2,
    )
    assert "VVs ended 3/3" in output
    for n, customer in [(1, "A"), (2, "B"), (3, "C")]:
        assert f"VV {n} (Customer {customer}): finished" in output
    # Both RVs flew through their MAVLink drivers, each to its own simulated copter.
    import sqlite3

    with sqlite3.connect(tmp_path / "db.sqlite3") as db:
        drivers = db.execute("SELECT name, driver, driver_url FROM fleet_vehicle").fetchall()
        flown = db.execute(
            "SELECT DISTINCT v.name FROM missions_task t JOIN fleet_vehicle v ON t.vehicle_id = v.id"
            " WHERE t.status = 'done'"
        ).fetchall()
        sources = dict(db.execute("SELECT name, sensor_sources FROM fleet_vehicle").fetchall())
    assert sorted(d[:2] for d in drivers) == [("Heli One", "mavlink"), ("Heli Two", "mavlink")]
    assert all(url.startswith("udpout:127.0.0.1:") for _, _, url in drivers)
    assert sorted(flown) == [("Heli One",), ("Heli Two",)]
    # Every reading came over MAVLink, as its copter published it (issue 24).
    for name in ("Heli One", "Heli Two"):
        assert json.loads(sources[name]) == {
            "Altimeter": {"source": "telemetry"},
            "Barometer": {"source": "telemetry"},
            "CO2": {"source": "named_value", "name": "CO2"},
            "Camera 640x480": {"source": "camera"},
            "GPS": {"source": "telemetry"},
            "NOx": {"source": "named_value", "name": "NOx"},
            "Thermometer": {"source": "telemetry"},
        }


def test_a_second_ctrl_c_right_after_the_first_hurries_the_stop_instead_of_breaking_it() -> None:
    """Two Ctrl-C in quick succession (CI saw the second land before the demo had printed that
    it was stopping): the first interrupts, the second only asks to kill what is left."""
    from vvm_worker.management.commands.demo import STOP_SIGNALS, Processes

    handlers = {each: signal.getsignal(each) for each in STOP_SIGNALS}
    processes = Processes({})
    try:
        processes.catch_interrupts()
        try:
            os.kill(os.getpid(), signal.SIGINT)  # its handler runs before the next bytecode
            raise AssertionError("the first Ctrl-C did not interrupt")
        except KeyboardInterrupt:
            os.kill(os.getpid(), signal.SIGINT)  # at once, inside the handling of the first
            os.kill(os.getpid(), signal.SIGTERM)
        assert processes.hurry.wait(timeout=5)
        assert processes.stop() == []
    finally:
        for each, handler in handlers.items():
            signal.signal(each, handler)


def test_a_closed_terminal_stops_the_demo_and_what_it_started(tmp_path: Path) -> None:
    """SIGHUP (the terminal the demo runs in is closed) stops it as Ctrl-C does: its workers
    and servers are not left running."""
    from vvm_worker.management.commands.demo import STOP_SIGNALS, Processes

    handlers = {each: signal.getsignal(each) for each in STOP_SIGNALS}
    processes = Processes(dict(os.environ))
    ready = tmp_path / "ready"
    try:
        processes.catch_interrupts()
        child = processes.start(  # a worker: it exits 0 on SIGTERM, once it has said it is up
            "sleeper",
            "-c",
            "import pathlib, signal, sys, time; "
            "signal.signal(signal.SIGTERM, lambda *_: sys.exit(0)); "
            f"pathlib.Path({str(ready)!r}).touch(); time.sleep(60)",
        )
        wait_until(ready.exists, timeout=30, what="the worker to start")
        try:
            os.kill(os.getpid(), signal.SIGHUP)
            raise AssertionError("the hang-up did not interrupt")
        except KeyboardInterrupt:
            pass
        assert processes.stop() == []
        assert child.poll() is not None
    finally:
        for each, handler in handlers.items():
            signal.signal(each, handler)


def test_the_demo_prints_the_logins_again_when_enter_is_pressed_in_its_terminal(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Pressing Enter in the demo's terminal prints the logins again, at once (the demo in the
    tests has no terminal: a pseudo-terminal stands for one here). A terminal whose foreground
    is not the demo's (a demo sent to the background) is left alone: reading it would stop the
    demo."""
    import pty

    from vvm_worker.management.commands.demo import EnterKey

    pressed: list[float] = []
    keyboard, terminal = pty.openpty()
    try:
        with open(terminal, closefd=False) as stdin:
            enter = EnterKey(stdin, pressed=lambda: pressed.append(time.monotonic()))
            assert enter.listening
            os.write(keyboard, b"logins?\n")
            enter.wait(0.05)  # not this test's controlling terminal: not its foreground
            assert pressed == []
            monkeypatch.setattr(enter, "_in_foreground", lambda: True)
            started = time.monotonic()
            enter.wait(10)
            assert len(pressed) == 1 and pressed[0] - started < 5  # at once, not after 10 s
            enter.wait(0.05)
            assert len(pressed) == 1  # once a press
    finally:
        os.close(keyboard)
        os.close(terminal)
    with open(os.devnull) as stdin:  # no terminal (a pipe, a service manager): it only waits
        assert not EnterKey(stdin, pressed=lambda: pressed.append(0)).listening


def test_the_demo_runs_the_examples_of_messages_and_pictures_only_next_to_its_default() -> None:
    """``make demo`` runs the paper's Figure 3 and the examples next to it; a scenario chosen
    with --scenario runs alone (its fleet as it is), unless --also adds another."""
    from vvm_worker.management.commands.demo import DEFAULT_ALSO, DEFAULT_SCENARIO, _scenario_paths

    fig2 = "examples/scenarios/paper-fig2.json"
    assert _scenario_paths({"scenario": None, "also": None}) == [
        str(DEFAULT_SCENARIO),
        str(DEFAULT_ALSO),
    ]
    assert DEFAULT_ALSO == ROOT / "examples" / "scenarios" / "messages-and-images.json"
    assert _scenario_paths({"scenario": fig2, "also": None}) == [fig2]
    assert _scenario_paths({"scenario": fig2, "also": ["a.json", "b.json"]}) == [
        fig2,
        "a.json",
        "b.json",
    ]
    assert _scenario_paths({"scenario": None, "also": ["a.json"]}) == [
        str(DEFAULT_SCENARIO),
        "a.json",
    ]


def test_the_simulated_copters_of_one_start_get_ports_of_their_own() -> None:
    """``demo --mavlink`` starts a simulated copter per RV, each on a loopback UDP port chosen
    before it binds: two given the same port share it, and each RV's worker talks to both
    (a fence uploaded to the wrong copter, which then refuses every flight)."""
    from vvm_worker.management.commands.demo import _free_udp_ports

    for _ in range(20):
        ports = _free_udp_ports(4)
        assert len(set(ports)) == 4, ports
        for port in ports:  # free to bind once the probes are gone
            with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as copter:
                copter.bind(("127.0.0.1", port))
