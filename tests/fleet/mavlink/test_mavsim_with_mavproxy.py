"""MavSim flown by MAVProxy (its command line, commands typed on its stdin): connect, arm,
take off, guided points ("guided LAT LNG ALT": MAV_CMD_DO_REPOSITION by default, a
MISSION_ITEM_INT with current=2 with guided_use_reposition off), a two-waypoint mission
("wp load", "mode auto") and RTL to the landing, asserted on mavsim's own state."""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import IO, Any

import pytest

from fleet.geo import Position, distance_m, offset
from fleet.mavlink import MavSim
from fleet.mavlink.wire import mavlink
from tests.fleet.mavlink.conftest import DEPOT
from tests.polling import wait_until

MAVPROXY = Path(sys.executable).with_name("mavproxy.py")
SPEED = 40.0
GUIDED = offset(DEPOT, north_m=90, east_m=-60, up_m=25)
GUIDED_AGAIN = offset(DEPOT, north_m=30, east_m=40, up_m=18)
HOLD_S = 20.0  # at the first waypoint: half a second of the test at SPEED
A = offset(DEPOT, north_m=-140, east_m=-50, up_m=30)
B = offset(DEPOT, north_m=-40, east_m=160, up_m=20)


class MavProxy:
    """mavproxy.py in a process of its own, its output in a log file."""

    def __init__(self, port: int, workdir: Path) -> None:
        assert MAVPROXY.exists(), f"no {MAVPROXY}: install the dev extra (pip install -e .[dev])"
        self.log = workdir / "mavproxy.log"
        out = self.log.open("wb")
        self.process = subprocess.Popen(
            [
                sys.executable, str(MAVPROXY), f"--master=udpout:127.0.0.1:{port}",
                "--no-state", "--default-modules=link,wp,param,arm,mode,cmdlong,misc",
            ],
            cwd=workdir,
            env={**os.environ, "HOME": str(workdir), "MAVLINK20": "1"},
            stdin=subprocess.PIPE,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        out.close()
        assert self.process.stdin is not None
        self.stdin: IO[bytes] = self.process.stdin

    def type(self, line: str) -> None:
        self.stdin.write(line.encode() + b"\n")
        self.stdin.flush()

    def output(self) -> str:
        return self.log.read_text(errors="replace")

    def eventually(self, condition: Callable[[], Any], what: str, timeout: float = 10.0) -> None:
        """Wait until ``condition`` holds while MAVProxy runs (failing with its output)."""

        def holds() -> Any:
            assert self.process.poll() is None, f"MAVProxy exited\n{self.output()}"
            return condition()

        wait_until(
            holds,
            timeout=timeout,
            what=what,
            details=lambda: self.output()[-3000:],
            interval=0.01,
        )

    def close(self) -> None:
        if self.process.poll() is None:
            try:
                self.type("exit")
                self.stdin.close()
                self.process.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                self.process.kill()
                self.process.wait()


@pytest.fixture
def mavproxy(port: int, tmp_path: Path) -> Iterator[MavProxy]:
    proxy = MavProxy(port, tmp_path)
    yield proxy
    proxy.close()


def waypoint_file(path: Path, items: list[tuple[Position, float]]) -> Path:
    """A QGC WPL 110 mission: home first, as ArduPilot keeps it, then the waypoints (each
    with its hold time)."""
    lines = ["QGC WPL 110"]
    lines.append(f"0\t1\t0\t16\t0\t0\t0\t0\t{DEPOT.lat:.7f}\t{DEPOT.lng:.7f}\t0\t1")
    relative = mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT
    for seq, (p, hold) in enumerate(items, start=1):
        lines.append(
            f"{seq}\t0\t{relative}\t16\t{hold:g}\t0\t0\t0\t{p.lat:.7f}\t{p.lng:.7f}\t{p.alt:g}\t1"
        )
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.mark.slow
def test_mavproxy_flies_guided_a_mission_and_home(
    make_sim: Callable[..., MavSim], mavproxy: MavProxy, tmp_path: Path
) -> None:
    sim = make_sim(speed=SPEED)
    # MAVProxy starts in a few seconds (it imports a lot) and then says hello.
    mavproxy.eventually(lambda: sim.gcs_heartbeats > 0, "heartbeat from MAVProxy", timeout=60)
    mavproxy.eventually(lambda: "STABILIZE" in mavproxy.output(), "the vehicle's mode shown")

    mavproxy.type("mode guided")
    mavproxy.eventually(lambda: sim.mode == "GUIDED", "GUIDED")
    mavproxy.type("arm throttle")
    mavproxy.eventually(lambda: sim.armed, "arming")
    mavproxy.type("takeoff 12")
    mavproxy.eventually(lambda: abs(sim.position().alt - 12) < 0.05, "the take-off")

    mavproxy.type(f"guided {GUIDED.lat:.7f} {GUIDED.lng:.7f} {GUIDED.alt:g}")
    mavproxy.eventually(lambda: distance_m(sim.position(), GUIDED) < 0.5, "the guided point")
    assert sim.commands_seen(mavlink.MAV_CMD_DO_REPOSITION) == [0]
    mavproxy.type("set guided_use_reposition 0")  # the older "guided goto" waypoint instead
    mavproxy.type(f"guided {GUIDED_AGAIN.lat:.7f} {GUIDED_AGAIN.lng:.7f} {GUIDED_AGAIN.alt:g}")
    mavproxy.eventually(
        lambda: distance_m(sim.position(), GUIDED_AGAIN) < 0.5, "the second guided point"
    )
    assert sim.commands_seen(mavlink.MAV_CMD_DO_REPOSITION) == [0]

    mission = waypoint_file(tmp_path / "two.txt", [(A, HOLD_S), (B, 0.0)])
    mavproxy.type(f"wp load {mission}")
    mavproxy.eventually(
        lambda: len(sim.mission_items(mavlink.MAV_MISSION_TYPE_MISSION)) == 3, "the upload"
    )
    mavproxy.type("mode auto")
    mavproxy.eventually(lambda: sim.mode == "AUTO", "AUTO")
    mavproxy.eventually(lambda: distance_m(sim.position(), A) < 0.5, "the first waypoint")
    mavproxy.eventually(lambda: distance_m(sim.position(), B) < 0.5, "the second waypoint")
    # MAVProxy prints what it hears: MISSION_CURRENT and ArduPilot's "Mission: 2 WP".
    mavproxy.eventually(lambda: "AP: Mission: 2 WP" in mavproxy.output(), "the report")
    assert "waypoint 2" in mavproxy.output()

    mavproxy.type("rtl")
    mavproxy.eventually(lambda: sim.mode == "RTL", "RTL")
    mavproxy.eventually(lambda: sim.on_ground and not sim.armed, "the landing")
    assert distance_m(sim.position(), DEPOT) < 0.5
