"""Flight logs (.tlog): a mavsim flight recorded by the MAVLink driver, and a simulated RV's
log made from its track, both read back by pymavlink and by its mavlogdump.py."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from pymavlink import mavutil

from fleet.geo import Position, distance_m, ground_distance_m, interpolate, offset
from fleet.mavlink import MavlinkDriver, MavSim
from fleet.mavlink.tlog import TlogRecorder, tlog_entry
from fleet.mavlink.tlog_sim import simulated_tlog
from tests.fleet.mavlink.conftest import DEPOT, SPEC, sim_clock, wait_until

SPEED = 40.0
TARGET = offset(DEPOT, north_m=-200, east_m=-120, up_m=40)
EPOCH_S = 1_735_689_600.0  # vvm_worker.clock.SIM_EPOCH_S


def read_tlog(path: Path) -> list[Any]:
    """Every message of a .tlog as pymavlink's reader gives it (with ``_timestamp``)."""
    log = mavutil.mavlink_connection(str(path))
    out = []
    while (msg := log.recv_match()) is not None:
        assert msg.get_type() != "BAD_DATA"
        out.append(msg)
    log.close()
    return out


def mavlogdump_positions(path: Path) -> list[dict[str, Any]]:
    """GLOBAL_POSITION_INT of a .tlog as mavlogdump.py prints it (JSON lines)."""
    script = shutil.which("mavlogdump.py", path=str(Path(sys.executable).parent))
    command = [script] if script else [sys.executable, "-m", "pymavlink.tools.mavlogdump"]
    done = subprocess.run(
        [*command, "--format", "json", "--types", "GLOBAL_POSITION_INT", str(path)],
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    return [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]


def at(msg: Any) -> Position:
    return Position(msg.lat / 1e7, msg.lon / 1e7, msg.relative_alt / 1000)


def test_a_record_is_a_big_endian_microsecond_stamp_then_the_frame() -> None:
    assert tlog_entry(1.000001, b"\xfd") == (1_000_000).to_bytes(8, "big") + b"\xfd"
    with pytest.raises(ValueError, match="before 1970"):
        tlog_entry(-1.0, b"")
    recorder = TlogRecorder(max_bytes=20, clock=lambda: 2.0)
    recorder.record(b"ignored: not recording")
    assert recorder.finish() is None
    recorder.start()
    recorder.record(b"0123456789")  # 18 bytes with its stamp
    recorder.record(b"0123456789")  # over the cap: dropped
    log = recorder.finish()
    assert log is not None and recorder.dropped == 1
    with log:
        assert log.read() == tlog_entry(2.0, b"0123456789")


def test_a_mavsim_flight_log_reads_back_with_the_track_the_driver_saw(
    make_sim: Callable[..., MavSim], port: int, tmp_path: Path
) -> None:
    make_sim(speed=SPEED)
    driver = MavlinkDriver(
        f"udpout:127.0.0.1:{port}",
        spec=SPEC,
        depot=DEPOT,
        clock=sim_clock(SPEED),
        telemetry_hz=20.0,
        command_timeout_s=0.5,
    )
    seen: dict[int, Position] = {}  # by time_boot_ms: what the driver was told
    try:
        driver.connect(timeout_s=5.0)
        driver.link.add_listener(
            "GLOBAL_POSITION_INT", lambda msg: seen.__setitem__(msg.time_boot_ms, at(msg))
        )
        clock = driver.clock
        driver.flight_log.start()  # the take-off
        driver.fly_to(TARGET, clock())
        wait_until(lambda: driver.has_arrived(TARGET, 1.0), what="the arrival")
        driver.return_to_depot(clock())
        wait_until(lambda: driver.is_landed_at(clock()), what="the landing")
        # (The disarming heartbeat may come before the last position report.)
        wait_until(lambda: driver.position_at(clock()).alt < 0.1, what="the report on the ground")
        log = driver.flight_log.finish()
    finally:
        driver.close()
    assert log is not None
    path = tmp_path / "flight.tlog"
    with log, path.open("wb") as out:
        shutil.copyfileobj(log, out)

    messages = read_tlog(path)
    kinds = {m.get_type() for m in messages}
    # Both ways: the vehicle's telemetry and our commands and heartbeats.
    assert {"HEARTBEAT", "GLOBAL_POSITION_INT", "SYS_STATUS", "COMMAND_ACK"} <= kinds
    assert {"COMMAND_LONG", "SET_POSITION_TARGET_GLOBAL_INT"} & kinds
    stamps = [m._timestamp for m in messages]
    assert stamps == sorted(stamps) and stamps[-1] - stamps[0] > 1.0
    track = [m for m in messages if m.get_type() == "GLOBAL_POSITION_INT"]
    assert [m.time_boot_ms for m in track] == sorted({m.time_boot_ms for m in track})
    # The log's positions are the ones the driver got, from the depot out to the target and
    # back down at the depot.
    assert all(distance_m(at(m), seen[m.time_boot_ms]) < 0.01 for m in track)
    # (The first report may come a few metres up: one comes every 2 s simulated, climbing 3 m/s.)
    assert ground_distance_m(at(track[0]), DEPOT) < 1.0 and at(track[0]).alt < 10.0
    assert min(distance_m(at(m), TARGET) for m in track) < 1.0
    assert distance_m(at(track[-1]), DEPOT) < 1.0

    dumped = mavlogdump_positions(path)
    assert [(d["data"]["lat"], d["data"]["lon"]) for d in dumped] == [(m.lat, m.lon) for m in track]
    assert [d["meta"]["timestamp"] for d in dumped] == pytest.approx([m._timestamp for m in track])


def test_a_simulated_flight_log_follows_its_track(tmp_path: Path) -> None:
    start_s = 1000.0
    top = DEPOT.with_alt(40.0)
    # Up 40 m, 233 m out at 10 m/s, back, down: a simulated RV's legs.
    points = [(start_s, DEPOT), (start_s + 13, top), (start_s + 36, TARGET)]
    points += [(start_s + 60, top), (start_s + 73, DEPOT)]
    track = [(t, p.lat, p.lng, p.alt) for t, p in points]
    path = tmp_path / "simulated.tlog"
    path.write_bytes(
        simulated_tlog(track, epoch_s=EPOCH_S, system_id=7, battery_start=0.9, battery_end=0.6)
    )

    messages = read_tlog(path)
    assert {m.get_srcSystem() for m in messages} == {7}
    kinds = [m.get_type() for m in messages]
    # The simulator's rates: a heartbeat a second (and one more as it disarms), positions at
    # the driver's 4 Hz.
    assert kinds.count("HEARTBEAT") == 74 + 1
    assert kinds.count("GLOBAL_POSITION_INT") == 73 * 4 + 1
    assert {"SYS_STATUS", "GPS_RAW_INT"} <= set(kinds)
    beats = [m for m in messages if m.get_type() == "HEARTBEAT"]
    assert beats[0].base_mode & 128 and not beats[-1].base_mode & 128  # armed, then not
    batteries = [m.battery_remaining for m in messages if m.get_type() == "SYS_STATUS"]
    assert (batteries[0], batteries[-1]) == (90, 60)

    positions = [m for m in messages if m.get_type() == "GLOBAL_POSITION_INT"]
    assert positions[0]._timestamp == pytest.approx(EPOCH_S + start_s)
    assert positions[-1]._timestamp == pytest.approx(EPOCH_S + start_s + 73)
    for msg in positions:
        t = msg._timestamp - EPOCH_S
        i = max(j for j, (s, _) in enumerate(points) if s <= t or j == 0)
        i = min(i, len(points) - 2)
        (t0, a), (t1, b) = points[i], points[i + 1]
        expected = interpolate(a, b, (t - t0) / (t1 - t0))
        assert distance_m(at(msg), expected) < 0.05
    assert distance_m(at(positions[144]), TARGET) < 0.05  # 36 s in

    dumped = mavlogdump_positions(path)
    assert [(d["data"]["lat"], d["data"]["lon"]) for d in dumped] == [
        (m.lat, m.lon) for m in positions
    ]
