"""Tests of the scenario parser (pure Python, no Django, no database)."""

from __future__ import annotations

import copy
import json
import pickle
import re
from pathlib import Path
from typing import Any

import pytest

from fleet.geo import Position
from vvm_worker.scenario import (
    FleetEvent,
    Scenario,
    ScenarioError,
    load_scenario,
    parse_scenario,
    vv_instances,
)

EXAMPLES = Path(__file__).resolve().parents[2] / "examples" / "scenarios"

DELETE = object()

SQUARE = [[48.0, 12.0], [48.0, 12.01], [48.01, 12.01], [48.01, 12.0], [48.0, 12.0]]


def _vehicle(name: str = "Heli One") -> dict[str, Any]:
    return {
        "name": name,
        "depot": [48.005, 12.005, 0],
        "area": copy.deepcopy(SQUARE),
        "min_altitude_m": 0,
        "max_altitude_m": 120.5,
        "max_speed_mps": 10,
        "sensors": ["CO2", "Thermometer"],
    }


VALID: dict[str, Any] = {
    "name": "Test",
    "ground_stations": [{"name": "GS Base", "position": [48.0, 12.0, 0]}],
    "vehicles": [_vehicle("Heli One"), _vehicle("Heli Two")],
    "customers": [
        {"name": "Customer A", "max_parallel_vvs": 2},
        {"name": "Customer B", "max_parallel_vvs": 1},
    ],
    "vvs": [
        {"customer": "Customer A", "name": "VV 1", "source": "VV.log('a');"},
        {"customer": "Customer B", "name": "VV 1", "source": "VV.log('b');"},
    ],
}


def variant(*changes: tuple[str, Any]) -> dict[str, Any]:
    """A deep copy of VALID with each (dotted path, value) set, or deleted for DELETE.

    An index one past the end of a list appends.
    """
    data = copy.deepcopy(VALID)
    for dotted, value in changes:
        *parents, last = [int(p) if p.isdigit() else p for p in dotted.split(".")]
        target: Any = data
        for part in parents:
            target = target[part]
        if value is DELETE:
            del target[last]
        elif isinstance(target, list) and last == len(target):
            target.append(value)
        else:
            target[last] = value
    return data


def parse(data: Any, base_dir: Path | None = None) -> Scenario:
    return parse_scenario(data, base_dir=base_dir or Path("/nonexistent"))


def raises(data: Any, pattern: str, base_dir: Path | None = None) -> ScenarioError:
    with pytest.raises(ScenarioError, match=pattern) as info:
        parse(data, base_dir)
    return info.value


# --- the shipped examples ----------------------------------------------------------------------


@pytest.mark.parametrize(
    ("file", "vehicles"),
    [("paper-fig2.json", ["Heli One"]), ("paper-fig3.json", ["Heli One", "Heli Two"])],
)
def test_paper_examples_load(file: str, vehicles: list[str]) -> None:
    scenario = load_scenario(EXAMPLES / file)

    assert scenario.path == (EXAMPLES / file).resolve()
    assert "paper, Figure" in scenario.name
    assert [gs.name for gs in scenario.ground_stations] == ["GS Base"]
    assert scenario.ground_stations[0].position == Position(48.1132, 12.8598, 0)
    assert [v.name for v in scenario.vehicles] == vehicles
    for vehicle in scenario.vehicles:
        assert vehicle.area[0] == vehicle.area[-1]
        assert len(vehicle.area) == 5
        assert vehicle.driver == "sim"
        assert vehicle.max_altitude_m == 120.0
        assert "CO2" in vehicle.sensors
    assert [c.name for c in scenario.customers] == ["Customer A", "Customer B", "Customer C"]
    assert [(vv.customer, vv.name) for vv in scenario.vvs] == [
        ("Customer A", "VV 1"),
        ("Customer B", "VV 2"),
        ("Customer C", "VV 3"),
    ]
    for k, vv in enumerate(scenario.vvs, start=1):
        assert "VV.task.execute" in vv.source
        assert vv.program_path == (EXAMPLES.parent / "vv" / f"vv{k}-paper.js").resolve()
    assert scenario.events == ()
    assert scenario.sensors == ()


def test_paper_fig3_areas_split_the_field() -> None:
    one, two = load_scenario(EXAMPLES / "paper-fig3.json").vehicles

    assert max(lng for _, lng in one.area) == min(lng for _, lng in two.area) == 12.864


# --- a valid document, all fields --------------------------------------------------------------


def test_optional_fields_are_parsed(tmp_path: Path) -> None:
    (tmp_path / "vv").mkdir()
    (tmp_path / "vv" / "p.js").write_text("// é\nVV.log(1);\n", encoding="utf-8")
    data = variant(
        ("description", "two helis"),
        ("vehicles.0.driver", "mavlink"),
        ("vehicles.0.driver_url", "udp:127.0.0.1:14550"),
        ("vehicles.0.battery_s", 900),
        ("vehicles.0.climb_rate_mps", 2.5),
        ("customers.0.privileged", True),
        ("customers.0.max_tasks_per_vv", 100),
        ("customers.0.storage_bytes", 1_000_000),
        ("customers.0.max_queued_vvs", 500),
        ("vvs.0", {"customer": "Customer A", "name": "F", "program": "vv/p.js"}),
        ("vvs.1.submit_at_s", 12.5),
        (
            "sensors",
            [{"name": "Lux", "kind": "scalar", "unit": "lx", "params": {"max": 1e5}}],
        ),
    )

    scenario = parse(data, tmp_path)

    heli = scenario.vehicles[0]
    assert (heli.driver, heli.driver_url, heli.battery_s, heli.climb_rate_mps) == (
        "mavlink",
        "udp:127.0.0.1:14550",
        900.0,
        2.5,
    )
    assert scenario.vehicles[1].driver == "sim"
    assert scenario.vehicles[1].battery_s is None
    assert heli.depot == Position(48.005, 12.005, 0.0)
    assert heli.area == tuple((lat, lng) for lat, lng in SQUARE)
    customer = scenario.customers[0]
    assert (customer.privileged, customer.max_tasks_per_vv, customer.storage_bytes) == (
        True,
        100,
        1_000_000,
    )
    assert customer.max_queued_vvs == 500
    assert scenario.customers[1].privileged is False
    assert scenario.customers[1].max_tasks_per_vv is None
    assert scenario.customers[1].max_queued_vvs is None
    assert scenario.vvs[0].source == "// é\nVV.log(1);\n"
    assert scenario.vvs[0].program_path == (tmp_path / "vv" / "p.js").resolve()
    assert scenario.vvs[1].submit_at_s == 12.5
    (lux,) = scenario.sensors
    assert (lux.name, lux.kind, lux.unit, dict(lux.params), lux.privileged) == (
        "Lux",
        "scalar",
        "lx",
        {"max": 1e5},
        False,
    )
    assert scenario.description == "two helis"
    assert scenario.path is None


def test_inline_source_is_kept_verbatim() -> None:
    source = "var x = 1;\nVV.storage.store('x', x);\n"
    scenario = parse(variant(("vvs.0.source", source)))

    assert scenario.vvs[0].source == source
    assert scenario.vvs[0].program_path is None


def test_missing_name_defaults_to_the_file_stem(tmp_path: Path) -> None:
    file = tmp_path / "my-test.json"
    file.write_text(json.dumps(variant(("name", DELETE))), encoding="utf-8")

    assert load_scenario(file).name == "my-test"


# --- keys and types ----------------------------------------------------------------------------


def test_unknown_key_names_key_path_and_allowed_keys() -> None:
    err = raises(
        variant(("vehicles.1.speed", 3)),
        re.escape("vehicles[1]: unknown key 'speed' (allowed: area, battery_s, climb_rate_mps,"),
    )
    assert err.path == "vehicles[1]"
    assert "sensors" in err.message


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (("colour", "red"), "^unknown key 'colour'"),
        (("ground_stations.0.alt", 3), r"^ground_stations\[0\]: unknown key 'alt'"),
        (("customers.0.quota", 3), r"^customers\[0\]: unknown key 'quota'"),
        (("vvs.0.priority", 3), r"^vvs\[0\]: unknown key 'priority'"),
    ],
)
def test_unknown_keys_at_every_level(change: tuple[str, Any], where: str) -> None:
    raises(variant(change), where)


@pytest.mark.parametrize(
    ("dotted", "where"),
    [
        ("vvs", "^missing required key 'vvs'"),
        ("vehicles.0.area", r"^vehicles\[0\]: missing required key 'area'"),
        ("customers.1.max_parallel_vvs", r"^customers\[1\]: missing required key"),
        ("ground_stations.0.position", r"^ground_stations\[0\]: missing required key 'position'"),
    ],
)
def test_missing_required_key(dotted: str, where: str) -> None:
    raises(variant((dotted, DELETE)), where)


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (("vehicles.0.max_speed_mps", True), r"^vehicles\[0\]\.max_speed_mps: must be a number"),
        (("vehicles.0.sensors", "CO2"), r"^vehicles\[0\]\.sensors: must be an array, got a string"),
        (("vehicles.0.depot.2", "10"), r"^vehicles\[0\]\.depot\[2\]: must be a number"),
        (("customers.0.name", 7), r"^customers\[0\]\.name: must be a string"),
        (("customers.0.privileged", "yes"), r"^customers\[0\]\.privileged: must be true or false"),
        (("customers.0.max_parallel_vvs", 1.5), r"max_parallel_vvs: must be a whole number"),
        (("vvs", {}), "^vvs: must be an array, got an object"),
        (("vehicles.0.battery_s", None), r"^vehicles\[0\]\.battery_s: must be a number, got null"),
    ],
)
def test_wrong_types(change: tuple[str, Any], where: str) -> None:
    raises(variant(change), where)


def test_message_quotas_are_parsed_and_left_out_ones_keep_the_default() -> None:
    scenario = parse(
        variant(("customers.0.max_messages_per_vv", 20), ("customers.0.max_message_bytes", 512))
    )

    first, second = scenario.customers
    assert (first.max_messages_per_vv, first.max_message_bytes) == (20, 512)
    assert (second.max_messages_per_vv, second.max_message_bytes) == (None, None)
    # A customer's VVs may be allowed no message at all.
    assert (
        parse(variant(("customers.0.max_messages_per_vv", 0))).customers[0].max_messages_per_vv == 0
    )


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (
            ("customers.0.max_messages_per_vv", -1),
            r"^customers\[0\]\.max_messages_per_vv: must be at least 0, got -1",
        ),
        (
            ("customers.0.max_messages_per_vv", 2.5),
            r"^customers\[0\]\.max_messages_per_vv: must be a whole number",
        ),
        (
            ("customers.0.max_message_bytes", 1),
            r"^customers\[0\]\.max_message_bytes: must be at least 2, got 1",
        ),
        (
            ("customers.1.max_message_bytes", "64k"),
            r"^customers\[1\]\.max_message_bytes: must be a number, got a string",
        ),
    ],
)
def test_bad_message_quotas_are_refused_with_where_and_why(
    change: tuple[str, Any], where: str
) -> None:
    raises(variant(change), where)


def test_a_document_that_is_not_an_object() -> None:
    raises([VALID], "^must be an object, got an array")


# --- positions and areas -----------------------------------------------------------------------


def test_latitude_out_of_range() -> None:
    raises(
        variant(("ground_stations.0.position", [91, 12, 0])),
        r"^ground_stations\[0\]\.position: latitude 91.0 is outside -90..90",
    )


def test_longitude_out_of_range_in_area() -> None:
    raises(
        variant(("vehicles.0.area.2", [48.01, 181])),
        r"^vehicles\[0\]\.area\[2\]: longitude 181.0 is outside",
    )


def test_position_needs_three_values() -> None:
    raises(variant(("vehicles.0.depot", [48.0, 12.0])), r"depot: must be \[lat, lng, alt\]")


def test_area_with_too_few_distinct_points() -> None:
    raises(
        variant(("vehicles.0.area", [[48, 12], [48, 12.01], [48, 12], [48, 12]])),
        r"^vehicles\[0\]\.area: a polygon needs at least 3 distinct points, got 2",
    )


def test_area_not_closed() -> None:
    raises(
        variant(("vehicles.1.area", SQUARE[:-1])),
        r"^vehicles\[1\]\.area: the polygon is not closed: the first point \[48.0, 12.0\] "
        r"differs from the last \[48.01, 12.0\]",
    )


def test_self_intersecting_area() -> None:
    bowtie = [[48.0, 12.0], [48.01, 12.01], [48.0, 12.01], [48.01, 12.0], [48.0, 12.0]]
    raises(
        variant(("vehicles.0.area", bowtie)),
        r"^vehicles\[0\]\.area: invalid polygon: Self-intersection\[48.005 12.005\]",
    )


# --- vehicle limits ----------------------------------------------------------------------------


def test_min_altitude_above_max() -> None:
    raises(
        variant(("vehicles.0.min_altitude_m", 130)),
        r"^vehicles\[0\]\.min_altitude_m: min_altitude_m \(130\) is above max_altitude_m \(120.5\)",
    )


def test_negative_altitude() -> None:
    raises(
        variant(("vehicles.0.min_altitude_m", -1)),
        r"^vehicles\[0\]\.min_altitude_m: must not be negative, got -1",
    )


@pytest.mark.parametrize("speed", [0, -2.5])
def test_speed_must_be_positive(speed: float) -> None:
    raises(
        variant(("vehicles.0.max_speed_mps", speed)),
        r"^vehicles\[0\]\.max_speed_mps: must be greater than 0",
    )


def test_empty_sensor_list_and_blank_sensor_name() -> None:
    raises(variant(("vehicles.0.sensors", [])), r"^vehicles\[0\]\.sensors: .*at least one sensor")
    raises(variant(("vehicles.0.sensors", ["CO2", " "])), r"^vehicles\[0\]\.sensors\[1\]: must not")


def test_unknown_driver() -> None:
    raises(
        variant(("vehicles.0.driver", "ros")),
        r"^vehicles\[0\]\.driver: unknown driver 'ros' \(one of: sim, mavlink\)",
    )


# --- names -------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (
            ("ground_stations.1", {"name": "GS Base", "position": [48, 12, 0]}),
            r"^ground_stations\[1\]\.name: duplicate ground station name 'GS Base' "
            r"\(also at ground_stations\[0\]\.name\)",
        ),
        (("vehicles.1.name", "Heli One"), r"^vehicles\[1\]\.name: duplicate vehicle name"),
        (("customers.1.name", "Customer A"), r"^customers\[1\]\.name: duplicate customer name"),
        (
            ("vvs.1.customer", "Customer A"),
            r"^vvs\[1\]\.name: duplicate VV name 'VV 1' for customer 'Customer A'",
        ),
    ],
)
def test_duplicate_names(change: tuple[str, Any], where: str) -> None:
    raises(variant(change), where)


def test_vv_of_unknown_customer() -> None:
    raises(
        variant(("vvs.1.customer", "Customer Z")),
        r"^vvs\[1\]\.customer: unknown customer 'Customer Z'",
    )


def test_max_parallel_vvs_at_least_one() -> None:
    raises(
        variant(("customers.1.max_parallel_vvs", 0)),
        r"^customers\[1\]\.max_parallel_vvs: must be at least 1, got 0",
    )


def test_a_ground_station_is_required_when_there_are_vvs() -> None:
    raises(variant(("ground_stations", [])), "^ground_stations: at least one ground station")
    assert parse(variant(("ground_stations", []), ("vvs", []))).vvs == ()


# --- VV programs -------------------------------------------------------------------------------


def test_program_and_source_are_exclusive(tmp_path: Path) -> None:
    (tmp_path / "p.js").write_text("1;", encoding="utf-8")
    both = variant(("vvs.0.program", "p.js"))
    neither = variant(("vvs.0.source", DELETE))

    raises(both, r"^vvs\[0\]: give exactly one of 'program' \(a file\) and 'source'", tmp_path)
    raises(neither, r"^vvs\[0\]: give exactly one of 'program'", tmp_path)


def test_missing_program_file_shows_the_resolved_path(tmp_path: Path) -> None:
    (tmp_path / "scenarios").mkdir()
    data = variant(("vvs.0", {"customer": "Customer A", "name": "X", "program": "../vv/x.js"}))

    err = raises(data, r"^vvs\[0\]\.program: program file not found: ", tmp_path / "scenarios")
    assert err.message.endswith(str((tmp_path / "vv" / "x.js").resolve()))


def test_program_that_is_not_utf8(tmp_path: Path) -> None:
    (tmp_path / "p.js").write_bytes(b"VV.log('\xff');")
    data = variant(("vvs.0", {"customer": "Customer A", "name": "X", "program": "p.js"}))

    raises(data, r"^vvs\[0\]\.program: cannot read program file .*p\.js", tmp_path)


@pytest.mark.parametrize(
    ("change", "where"),
    [
        (("vvs.0.copies", 0), r"^vvs\[0\]\.copies: must be at least 1, got 0"),
        (("vvs.0.copies", 2.5), r"^vvs\[0\]\.copies: must be a whole number"),
        (("vvs.1.submit_at_s", -0.5), r"^vvs\[1\]\.submit_at_s: must not be negative"),
    ],
)
def test_copies_and_submit_time_ranges(change: tuple[str, Any], where: str) -> None:
    raises(variant(change), where)


def test_copies_expand_into_numbered_instances() -> None:
    scenario = parse(variant(("vvs.0.copies", 3), ("vvs.1.copies", 1.0)))

    instances = vv_instances(scenario)

    assert [(spec.customer, name) for spec, name in instances] == [
        ("Customer A", "VV 1 #1"),
        ("Customer A", "VV 1 #2"),
        ("Customer A", "VV 1 #3"),
        ("Customer B", "VV 1"),
    ]
    assert instances[0][0] is instances[2][0] is scenario.vvs[0]
    assert scenario.vvs[1].copies == 1


def test_copies_may_not_collide_with_another_vv_name() -> None:
    data = variant(
        ("vvs.0.copies", 2),
        ("vvs.1", {"customer": "Customer A", "name": "VV 1 #2", "source": ""}),
    )
    raises(data, r"^vvs\[1\]\.name: duplicate VV name 'VV 1 #2' .*\(also at vvs\[0\]\.name\)")


# --- SDC additions -----------------------------------------------------------------------------


def test_sensor_of_unknown_kind() -> None:
    data = variant(("sensors", [{"name": "Sonar", "kind": "audio", "unit": "dB"}]))
    raises(
        data, r"^sensors\[0\]\.kind: unknown sensor kind 'audio' \(one of: scalar, gps, camera\)"
    )


def test_sensor_params_are_a_read_only_copy() -> None:
    params = {"width": 320, "height": 240}
    data = variant(("sensors", [{"name": "Cam", "kind": "camera", "unit": "", "params": params}]))

    (cam,) = parse(data).sensors
    params["width"] = 1

    assert cam.params["width"] == 320
    with pytest.raises(TypeError):
        cam.params["width"] = 2  # type: ignore[index]


# --- events ------------------------------------------------------------------------------------


def test_events_are_sorted_stably_by_time() -> None:
    events = [
        {"at_s": 300, "vehicle": "Heli One", "action": "return"},
        {"at_s": 100, "vehicle": "Heli One", "action": "maintenance"},
        {"at_s": 300, "vehicle": "Heli Two", "action": "remove"},
        {"at_s": 0, "add_vehicle": _vehicle("Heli Three")},
    ]

    scenario = parse(variant(("events", events)))

    assert [(e.at_s, e.action, e.vehicle) for e in scenario.events] == [
        (0.0, "add", "Heli Three"),
        (100.0, "maintenance", "Heli One"),
        (300.0, "return", "Heli One"),
        (300.0, "remove", "Heli Two"),
    ]
    added = scenario.events[0].add_vehicle
    assert added is not None
    assert added.area[0] == added.area[-1]
    assert scenario.events[1] == FleetEvent(100.0, "maintenance", "Heli One", None)
    assert [v.name for v in scenario.vehicles] == ["Heli One", "Heli Two"]


def test_event_on_unknown_vehicle() -> None:
    data = variant(("events", [{"at_s": 5, "vehicle": "Heli Nine", "action": "remove"}]))
    raises(data, r"^events\[0\]\.vehicle: unknown vehicle 'Heli Nine'")


def test_event_on_a_vehicle_added_earlier_but_not_later() -> None:
    add = {"at_s": 10, "add_vehicle": _vehicle("Heli Three")}
    later = {"at_s": 20, "vehicle": "Heli Three", "action": "maintenance"}
    earlier = {"at_s": 5, "vehicle": "Heli Three", "action": "maintenance"}

    assert len(parse(variant(("events", [later, add]))).events) == 2
    raises(variant(("events", [add, earlier])), r"^events\[1\]\.vehicle: unknown vehicle")


def test_event_with_unknown_action() -> None:
    data = variant(("events", [{"at_s": 5, "vehicle": "Heli One", "action": "explode"}]))
    raises(data, r"^events\[0\]\.action: unknown action 'explode' \(one of: remove, maintenance")


def test_event_after_removal() -> None:
    events = [
        {"at_s": 5, "vehicle": "Heli One", "action": "remove"},
        {"at_s": 6, "vehicle": "Heli One", "action": "return"},
    ]
    raises(variant(("events", events)), r"^events\[1\]\.vehicle: vehicle 'Heli One' was already")


def test_add_vehicle_is_validated_like_a_vehicle() -> None:
    bad_area = _vehicle("Heli Three")
    bad_area["area"] = SQUARE[:-1]
    extra_key = _vehicle("Heli Three") | {"speed": 3}

    raises(
        variant(("events", [{"at_s": 1, "add_vehicle": bad_area}])),
        r"^events\[0\]\.add_vehicle\.area: the polygon is not closed",
    )
    raises(
        variant(("events", [{"at_s": 1, "add_vehicle": extra_key}])),
        r"^events\[0\]\.add_vehicle: unknown key 'speed'",
    )


def test_add_vehicle_name_must_be_new() -> None:
    data = variant(("events", [{"at_s": 1, "add_vehicle": _vehicle("Heli Two")}]))
    raises(
        data,
        r"^events\[0\]\.add_vehicle\.name: duplicate vehicle name 'Heli Two' "
        r"\(also at vehicles\[1\]\.name\)",
    )


def test_event_with_both_add_vehicle_and_vehicle() -> None:
    event = {"at_s": 1, "vehicle": "Heli One", "add_vehicle": _vehicle("Heli Three")}
    raises(variant(("events", [event])), r"^events\[0\]: an event has either 'add_vehicle' or")


# --- files -------------------------------------------------------------------------------------


def test_json_syntax_error_gives_line_and_column(tmp_path: Path) -> None:
    file = tmp_path / "broken.json"
    file.write_text('{\n  "name": "x",\n  "vvs": [,]\n}\n', encoding="utf-8")

    with pytest.raises(ScenarioError, match="invalid JSON at line 3, column 11") as info:
        load_scenario(file)

    assert (info.value.line, info.value.column) == (3, 11)
    assert str(info.value).startswith(f"{file}: invalid JSON")


def test_missing_scenario_file(tmp_path: Path) -> None:
    with pytest.raises(ScenarioError, match=r"no such file: .*nope\.json"):
        load_scenario(tmp_path / "nope.json")


def test_duplicate_json_key_is_an_error(tmp_path: Path) -> None:
    file = tmp_path / "dup.json"
    text = json.dumps(VALID)
    file.write_text(text[:-1] + ', "vvs": []}', encoding="utf-8")

    with pytest.raises(ScenarioError, match="key 'vvs' is given more than once"):
        load_scenario(file)


def test_errors_from_a_file_name_the_file_and_resolve_programs_next_to_it(
    tmp_path: Path,
) -> None:
    (tmp_path / "p.js").write_text("VV.log(1);", encoding="utf-8")
    good = variant(("vvs.0", {"customer": "Customer A", "name": "X", "program": "p.js"}))
    (tmp_path / "good.json").write_text(json.dumps(good), encoding="utf-8")
    bad = variant(("vehicles.0.max_speed_mps", 0))
    (tmp_path / "bad.json").write_text(json.dumps(bad), encoding="utf-8")

    assert load_scenario(tmp_path / "good.json").vvs[0].source == "VV.log(1);"
    with pytest.raises(ScenarioError) as info:
        load_scenario(tmp_path / "bad.json")
    err = info.value
    assert str(err) == f"{tmp_path / 'bad.json'}: vehicles[0].max_speed_mps: {err.message}"
    assert err.path == "vehicles[0].max_speed_mps"
    restored = pickle.loads(pickle.dumps(err))
    assert (str(restored), restored.path) == (str(err), err.path)


# --- no-fly zones --------------------------------------------------------------------------------

ZONE = [[48.004, 12.004], [48.004, 12.006], [48.006, 12.006], [48.006, 12.004], [48.004, 12.004]]


def test_no_fly_zones_are_parsed_with_their_bands() -> None:
    scenario = parse(
        variant(
            (
                "no_fly_zones",
                [
                    {"name": "Substation", "area": ZONE},
                    {"name": "Stadium", "area": ZONE, "min_altitude_m": 5, "max_altitude_m": 40},
                ],
            )
        )
    )
    first, second = scenario.no_fly_zones
    assert (first.name, first.min_altitude_m, first.max_altitude_m) == ("Substation", 0.0, None)
    assert first.area[0] == (48.004, 12.004)
    assert (second.min_altitude_m, second.max_altitude_m) == (5.0, 40.0)
    assert parse(VALID).no_fly_zones == ()


@pytest.mark.parametrize(
    ("zone", "pattern"),
    [
        ({"name": "Z", "area": ZONE[:-1]}, r"^no_fly_zones\[0\]\.area: the polygon is not closed"),
        (
            {"name": "Z", "area": ZONE, "min_altitude_m": 50, "max_altitude_m": 40},
            r"^no_fly_zones\[0\]\.max_altitude_m: max_altitude_m \(40\) is below "
            r"min_altitude_m \(50\)",
        ),
        ({"name": "Z", "area": ZONE, "ceiling": 3}, r"^no_fly_zones\[0\]: unknown key 'ceiling'"),
        ({"area": ZONE}, r"^no_fly_zones\[0\]: missing required key 'name'"),
    ],
)
def test_a_bad_no_fly_zone_names_where(zone: dict[str, Any], pattern: str) -> None:
    raises(variant(("no_fly_zones", [zone])), pattern)


def test_two_no_fly_zones_of_one_name() -> None:
    zone = {"name": "Z", "area": ZONE}
    raises(
        variant(("no_fly_zones", [zone, zone])),
        r"^no_fly_zones\[1\]\.name: duplicate no-fly zone name 'Z' \(also at no_fly_zones\[0\]",
    )


def test_a_simulated_aerial_vehicle_may_start_in_the_air_above_its_depot() -> None:
    scenario = parse(variant(("vehicles.0.start", [48.112, 12.861, 40.0])))
    assert scenario.vehicles[0].start == Position(48.112, 12.861, 40.0)
    assert scenario.vehicles[1].start is None  # landed at its depot
    raises(
        variant(("vehicles.0.start", [48.112, 12.861, 0.0])),
        r"^vehicles\[0\]\.start: a vehicle starts in the air, above its depot's 0 m, got 0 m",
    )
    raises(
        variant(("vehicles.0.start", [48.112, 12.861, 40.0]), ("vehicles.0.driver", "mavlink")),
        r"^vehicles\[0\]\.start: only a simulated aerial vehicle starts in the air",
    )
