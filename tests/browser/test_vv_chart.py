"""The VV page's chart plots the readings against the time they were taken (UTC clock times on
its axis), not against the order of the tasks; and offers the readings as CSV and GeoJSON."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest
from playwright.sync_api import expect

from missions.models import Task, TaskStatus, VirtualVehicle, VVStatus
from tests.browser.pages import log_in
from vvm_worker.clock import SIM_EPOCH_S

pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

CLOCK = r"^\d\d:\d\d:\d\d$"
MINUTES = r"^\d\d:\d\d$"


def co2(time: str, value: float) -> dict:
    where = {"lat": 48.1111, "lng": 12.8619, "alt": 50.0}
    return {
        "sensor": "CO2",
        "kind": "scalar",
        "time": time,
        "position": where,
        "value": value,
        "unit": "ppm",
    }


def finished_vv(world, name: str, readings: list[tuple[str, float]]) -> VirtualVehicle:
    """Customer A's finished VV with one CO2 reading a task (time, ppm), in task order."""
    vv = VirtualVehicle.objects.create(
        customer=world.customer_a,
        name=name,
        program="var a = 1;",
        status=VVStatus.FINISHED,
        seed=1,
        start_ms=int(SIM_EPOCH_S * 1000),
        submitted_s=0.0,
        finished_s=1900.0,
    )
    for index, (time, value) in enumerate(readings):
        Task.objects.create(
            vv=vv,
            q=1,
            index=index,
            lat=48.1111,
            lng=12.8619,
            alt=50.0,
            tolerance_m=2.0,
            sensors=["CO2"],
            status=TaskStatus.DONE,
            requested_s=0.0,
            done_s=1800.0,
            readings=[co2(time, value)],
        )
    return vv


@pytest.fixture
def surveyed(world) -> VirtualVehicle:
    """Customer A's finished VV: an executeAll batch of three tasks served out of order, the
    last reading half an hour after the first."""
    return finished_vv(
        world,
        "Survey",
        [
            ("2025-01-01T00:30:00.000Z", 420.0),
            ("2025-01-01T00:00:10.000Z", 418.0),
            ("2025-01-01T00:10:20.500Z", 419.0),
        ],
    )


X_AXIS = """() => {
  const chart = window.Chart.getChart(document.querySelector('#vv-charts canvas'));
  if (!chart || !chart.scales.x) return null;
  const x = chart.scales.x;
  return {
    points: chart.data.datasets[0].data,
    type: x.type,
    title: x.options.title.text,
    ticks: x.ticks.map((t) => t.label),
    origin: Number(document.getElementById('vv-charts').dataset.timeOrigin),
  };
}"""


def test_the_chart_plots_readings_against_their_time_in_utc(page, traffic, surveyed) -> None:
    log_in(page, "customer-a", then=f"/vvs/{surveyed.pk}/")
    canvas = page.locator("#vv-charts canvas")
    expect(canvas).to_have_count(1)
    chart = page.wait_for_function(X_AXIS).json_value()
    start_ms = SIM_EPOCH_S * 1000  # 2025-01-01 00:00 UTC
    assert chart["origin"] == start_ms
    # In the order they were taken, at their times: seconds after midnight UTC.
    assert [(p["t"], p["x"], p["y"], p["task"]) for p in chart["points"]] == [
        (start_ms + 10_000, 10, 418.0, "1.1"),
        (start_ms + 620_500, 620.5, 419.0, "1.2"),
        (start_ms + 1_800_000, 1800, 420.0, "1"),
    ]
    assert chart["type"] == "linear" and chart["title"] == "time (UTC)"
    assert len(chart["ticks"]) >= 3
    # Clock-round ticks: every five minutes over half an hour, in minutes.
    assert all(re.match(MINUTES, label) for label in chart["ticks"]), chart["ticks"]
    assert "00:05" in chart["ticks"] and "00:30" in chart["ticks"]

    with page.expect_download() as got:
        page.get_by_role("link", name="readings.csv").click()
    with Path(got.value.path()).open(newline="") as file:
        rows = list(csv.DictReader(file))
    assert [(row["time"], row["value"]) for row in rows] == [
        ("2025-01-01T00:00:10.000Z", "418.0"),
        ("2025-01-01T00:10:20.500Z", "419.0"),
        ("2025-01-01T00:30:00.000Z", "420.0"),
    ]
    with page.expect_download() as got:
        page.get_by_role("link", name="readings.geojson").click()
    features = json.loads(Path(got.value.path()).read_text())["features"]
    assert [f["geometry"]["coordinates"] for f in features] == [[12.8619, 48.1111, 50.0]] * 3


@pytest.mark.parametrize(
    ("readings", "unit", "must_show"),
    [
        ([("2025-01-01T06:32:40.000Z", 418.0)], CLOCK, "06:32:40"),  # one reading
        (
            [("2025-01-01T06:32:40.000Z", 418.0), ("2025-01-01T06:32:41.000Z", 419.0)],
            CLOCK,
            "06:32:40",
        ),  # a second apart
        (
            [("2025-01-01T06:30:00.000Z", 418.0), ("2025-01-01T09:45:00.000Z", 421.0)],
            MINUTES,
            "07:00",
        ),  # hours apart
    ],
    ids=["one reading", "a second apart", "hours apart"],
)
def test_the_time_axis_fits_its_unit_to_the_span_of_the_readings(
    page, traffic, world, readings, unit, must_show
) -> None:
    warnings: list[str] = []
    page.on("console", lambda m: warnings.append(m.text) if m.type == "warning" else None)
    vv = finished_vv(world, "Span", readings)
    log_in(page, "customer-a", then=f"/vvs/{vv.pk}/")
    ticks = page.wait_for_function(X_AXIS).json_value()["ticks"]
    # A few readable labels, none twice, in the unit the span asks for (seconds for a
    # minute, minutes for hours), never thousands of ticks printed over each other.
    assert 3 <= len(ticks) <= 12 and len(set(ticks)) == len(ticks), ticks
    assert all(re.match(unit, label) for label in ticks), ticks
    assert must_show in ticks, ticks
    assert not [w for w in warnings if "ticks" in w], warnings


def test_a_failed_vvs_map_shows_the_point_no_vehicle_could_serve(page, traffic, world) -> None:
    vv = finished_vv(world, "Too far", [("2025-01-01T00:00:10.000Z", 418.0)])
    VirtualVehicle.objects.filter(pk=vv.pk).update(
        status=VVStatus.FAILED,
        error="no vehicle can serve the task at (48.130000, 12.861900) at 50 m: it is outside "
        "every operation area (line 2, column 1)",
        error_line=2,
        error_column=1,
    )
    Task.objects.create(
        vv=vv,
        q=2,
        lat=48.13,
        lng=12.8619,
        alt=50.0,
        tolerance_m=2.0,
        sensors=["CO2"],
        status=TaskStatus.REJECTED,
        requested_s=20.0,
    )
    log_in(page, "customer-a", then=f"/vvs/{vv.pk}/")
    expect(page.locator("#vv-map")).to_have_attribute("data-tasks-refused", "1")
    # Its own page's map holds the refused point in view, with the task it did serve.
    in_view = page.evaluate(
        "() => [[48.13, 12.8619], [48.1111, 12.8619]]"
        ".map((p) => window.cpccMap.map.getBounds().contains(p))"
    )
    assert in_view == [True, True]
    expect(page.locator(".legend")).to_contain_text("refused task")
