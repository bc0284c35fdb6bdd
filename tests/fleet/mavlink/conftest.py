"""MAVLink over real loopback links: a MavSim on a free UDP port per test, and helpers to wait
for a condition with a deadline (never a fixed sleep)."""

from __future__ import annotations

import socket
import time
from collections.abc import Callable, Iterator
from typing import Any

import pytest

from fleet.geo import Position
from fleet.mavlink import MavSim
from fleet.simulation.vehicle import VehicleSpec
from tests import polling

# Heli One's depot and area in the paper's Figure 3 (tests/factories' AREA_ONE).
DEPOT = Position(48.1135, 12.86, 0.0)
AREA = [
    [48.109, 12.859],
    [48.109, 12.864],
    [48.114, 12.864],
    [48.114, 12.859],
    [48.109, 12.859],
]
SPEC = VehicleSpec(max_speed_mps=10.0, climb_rate_mps=3.0, battery_s=600.0)
# Simulated seconds per wall second: a 200 m flight at 10 m/s takes a second of the test.
SPEED = 20.0


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that nothing uses right now."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def free_tcp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        return int(probe.getsockname()[1])


def wait_until(condition: Callable[[], Any], *, timeout: float = 10.0, what: str = "it") -> Any:
    """``tests.polling.wait_until`` every 5 ms: mavsim flies many times faster than life."""
    return polling.wait_until(condition, timeout=timeout, what=what, interval=0.005)


def sim_clock(speed: float = SPEED) -> Callable[[], float]:
    """A platform clock that runs as fast as a MavSim at ``speed``."""
    return lambda: speed * time.monotonic()


@pytest.fixture
def port() -> int:
    return free_udp_port()


@pytest.fixture
def make_sim(port: int) -> Iterator[Callable[..., MavSim]]:
    """Start MavSims listening on ``udpin:127.0.0.1:<port>`` (Figure 3's Heli One by default);
    all are stopped at the end of the test."""
    sims: list[MavSim] = []

    def make(**options: Any) -> MavSim:
        options.setdefault("spec", SPEC)
        options.setdefault("depot", DEPOT)
        options.setdefault("speed", SPEED)
        connection = options.pop("connection", f"udpin:127.0.0.1:{port}")
        sim = MavSim(connection, **options).start()
        sims.append(sim)
        return sim

    yield make
    for sim in sims:
        sim.stop()
