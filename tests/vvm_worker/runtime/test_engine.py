"""The VV runtime: blocking VVM-API over deterministic replay (DESIGN.md section 2)."""

from __future__ import annotations

import pytest

from tests.conftest import PROGRAMS
from tests.vvm_worker.runtime.harness import (
    START_MS,
    Run,
    answer_with_readings,
    reject_all,
    through_json,
)
from vvm_worker.runtime import ErrorKind, Limits, Outcome, answer_task, check_syntax

PAPER_LOOP = """
var co2 = VV.sensor.get('CO2');
var temp = VV.sensor.get('Thermometer');
var points = [
  new VV.types.LatLngAlt(48.1111, 12.8619, 50),
  new VV.types.LatLngAlt(48.1112, 12.8631, 50),
  new VV.types.LatLngAlt(48.1115, 12.8646, 50),
];
for (var n = 0; n < points.length; ++n) {
  VV.task.execute(
    { type: 'point', position: points[n], tolerance: 2, sensors: [co2, temp] },
    function (data) {
      for (var k = 0; k < data.length; ++k) {
        VV.storage.store('p' + n + '.' + k, {iteration: n, value: data[k].value, sensor: data[k].sensor});
      }
    }
  );
}
"""


def test_paper_loop_callback_sees_its_own_iteration() -> None:
    run = Run(PAPER_LOOP)
    result = run.run()
    assert result.outcome is Outcome.FINISHED
    assert sorted(run.storage) == [f"p{n}.{k}" for n in range(3) for k in range(2)]
    for n in range(3):
        # The reading answering request n carries value n: the callback ran before execute
        # returned, so `n` was still that iteration's.
        assert run.storage[f"p{n}.0"] == {"iteration": n, "value": n, "sensor": "CO2"}
        assert run.storage[f"p{n}.1"] == {"iteration": n, "value": n, "sensor": "Thermometer"}


def test_paper_example_programs_ask_for_four_tasks_each_and_store_twelve_keys() -> None:
    for name in ("vv1-paper.js", "vv2-paper.js", "vv3-paper.js"):
        run = Run((PROGRAMS / name).read_text())
        assert run.run().outcome is Outcome.FINISHED
        assert len(run.journal) == 4
        assert sorted(run.storage) == sorted(f"p{n}.{k}" for n in range(4) for k in range(3))


def test_execute_blocks_until_the_task_is_done_and_returns_the_callback_data() -> None:
    run = Run(
        """
        var gps = VV.sensor.get('GPS');
        var seen = null;
        var data = VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3),
                                    tolerance: 1, sensors: [gps]}, function (d) { seen = d; });
        VV.storage.store('same', seen === data);
        VV.storage.store('sensor', data[0].sensor);
        """
    )
    first = run.step()
    assert first.outcome is Outcome.SUSPENDED
    assert first.effects == ()  # nothing after the blocking call has happened yet
    assert first.pending is not None and first.pending.tasks[0].sensors == ("GPS",)
    assert (first.pending.tasks[0].lat, first.pending.tasks[0].lng) == (1, 2)
    assert run.run().outcome is Outcome.FINISHED
    assert run.storage == {"same": True, "sensor": "GPS"}


STATEFUL = """
var gps = VV.sensor.get('GPS');
function counter() { var c = 0; return function () { return ++c; }; }
var next = counter();
var history = [];
for (var i = 0; i < 6; i++) {
  var r = Math.random();
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(10 + r, 20, 30), tolerance: 1,
                   sensors: [gps]}, function (d) {
    history.push([i, next(), r, Date.now()]);
    VV.storage.store('state-' + i, {history: history, r: Math.random()});
  });
  VV.log('step', i, JSON.stringify(history[history.length - 1]));
}
"""


def test_replay_after_migrations_gives_the_same_state_as_one_uninterrupted_run() -> None:
    migrated = Run(STATEFUL)
    assert migrated.run(migrate=through_json).outcome is Outcome.FINISHED
    # The same program given every answer at once runs in one go, never suspended or moved.
    straight = Run(STATEFUL, journal=list(migrated.journal))
    result = straight.step()
    assert result.outcome is Outcome.FINISHED
    assert straight.storage == migrated.storage
    assert straight.log == migrated.log
    assert migrated.storage["state-5"]["history"][-1][:2] == [5, 6]


def test_the_same_seed_gives_the_same_run_and_another_seed_another() -> None:
    a, b, c = Run(STATEFUL, seed=11), Run(STATEFUL, seed=11), Run(STATEFUL, seed=12)
    for run in (a, b, c):
        run.run()
    assert a.storage == b.storage and a.log == b.log
    assert a.storage["state-5"] != c.storage["state-5"]
    randoms = [h[2] for h in a.storage["state-5"]["history"]]
    assert len(set(randoms)) == 6 and all(0 <= r < 1 for r in randoms)


def test_date_is_the_logical_time_of_the_event_that_resumed_the_vv() -> None:
    run = Run(
        """
        VV.storage.store('start', Date.now());
        VV.storage.store('start-obj', new Date().getTime());
        VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,
                         sensors: [VV.sensor.get('GPS')]});
        VV.storage.store('after', Date.now());
        VV.storage.store('iso', new Date(0).toISOString());
        VV.storage.store('instance', new Date() instanceof Date);
        """
    )
    run.run()
    assert run.storage["start"] == START_MS
    assert run.storage["start-obj"] == START_MS
    assert run.storage["after"] == START_MS + 1000
    assert run.storage["iso"] == "1970-01-01T00:00:00.000Z"
    assert run.storage["instance"] is True


def test_suspension_passes_through_the_programs_catch_and_finally() -> None:
    run = Run(
        """
        var gps = VV.sensor.get('GPS');
        var t = {type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1, sensors: [gps]};
        var d = null, tries = 0, finals = 0;
        while (d === null) {
          tries++;
          try { d = VV.task.execute(t); } catch (e) { VV.log('caught', String(e)); } finally { finals++; }
        }
        try { VV.task.execute(t); } catch { VV.log('swallowed'); }
        try { VV.task.execute(t); } catch ({message}) { VV.log('destructured', message); }
        VV.storage.store('counts', [tries, finals]);
        """
    )
    assert run.run().outcome is Outcome.FINISHED
    assert run.storage["counts"] == [1, 1]
    assert run.log == []
    assert len(run.journal) == 3


def test_a_rejected_task_throws_task_rejected_error_that_the_program_can_catch() -> None:
    run = Run(
        """
        try {
          VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,
                           sensors: [VV.sensor.get('GPS')]});
        } catch (e) {
          VV.storage.store('error', [e.name, e.message, e instanceof Error, e instanceof TaskRejectedError]);
        }
        VV.storage.store('went on', true);
        """
    )
    assert run.run(answer=reject_all("outside every operation area")).outcome is Outcome.FINISHED
    assert run.storage["error"] == ["TaskRejectedError", "outside every operation area", True, True]
    assert run.storage["went on"] is True


def test_an_uncaught_rejection_fails_the_vv_with_the_message_and_line() -> None:
    run = Run(
        "var gps = VV.sensor.get('GPS');\n"
        "VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1, sensors: [gps]});\n"
    )
    result = run.run(answer=reject_all("no vehicle can serve it"))
    assert result.outcome is Outcome.FAILED
    assert result.error is not None
    assert "TaskRejectedError: no vehicle can serve it" in result.error.message
    assert result.error.line == 2


def test_a_program_that_throws_fails_with_the_message_and_line() -> None:
    run = Run("var a = 1;\nVV.log('before');\nnull.x;\nVV.log('after');\n")
    result = run.run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None and result.error.kind is ErrorKind.RUNTIME
    assert result.error.message.startswith("TypeError: Cannot read properties of null")
    assert (result.error.line, result.error.column) == (3, 6)
    assert "line 3" in str(result.error)
    assert run.log == ["before"]  # what happened before the error stays


def test_throwing_a_plain_value_still_names_the_line() -> None:
    result = Run("var x = 1;\n\nthrow 'gave up';\n").run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None
    assert (result.error.message, result.error.line) == ("gave up", 3)


def test_a_syntax_error_fails_the_vv_with_line_and_column() -> None:
    result = Run("var a = 1;\nvar b = ;\n").run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None and result.error.kind is ErrorKind.SYNTAX
    assert (result.error.line, result.error.column) == (2, 9)
    assert "Unexpected token" in result.error.message


def test_check_syntax_does_not_run_the_program() -> None:
    assert check_syntax("while (true) {}") is None
    problem = check_syntax("function f( {\n}")
    assert problem is not None and (problem.line, problem.column) == (2, 2)
    strict = check_syntax("'use strict';\nwith (Math) { max(1, 2); }")
    assert strict is not None and strict.line == 2


def test_an_unknown_sensor_throws_an_error_that_names_it() -> None:
    run = Run("VV.sensor.get('Geiger counter');")
    result = run.run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None
    assert "'Geiger counter'" in result.error.message or '"Geiger counter"' in result.error.message
    assert result.error.line == 1


def test_sensor_list_has_name_description_kind_unit_params() -> None:
    run = Run(
        "VV.storage.store('list', VV.sensor.list()); VV.storage.store('one', VV.sensor.get('CO2'));"
    )
    run.run()
    names = [e["name"] for e in run.storage["list"]]
    assert names == ["CO2", "Thermometer", "GPS", "Camera 640x480"]
    assert run.storage["one"] == {
        "name": "CO2",
        "description": "CO2",
        "kind": "scalar",
        "unit": "ppm",
        "params": {"quantity": "co2"},
    }


@pytest.mark.parametrize(
    ("args", "words"),
    [
        ("200, 12, 50", "latitude 200 is outside -90..90"),
        ("48, 190, 50", "longitude 190 is outside -180..180"),
        ("48, 12, -11001", "altitude -11001 is outside"),
        ("'north', 12, 5", "latitude must be a finite number"),
    ],
)
def test_out_of_range_positions_throw(args: str, words: str) -> None:
    run = Run(
        f"try {{ new VV.types.LatLngAlt({args}); }} catch (e) {{ VV.storage.store('e', e.name + ': ' + e.message); }}"
    )
    run.run()
    assert words in run.storage["e"]
    assert run.storage["e"].startswith("RangeError")


def test_positions_have_fields_and_getters() -> None:
    run = Run(
        "var p = new VV.types.LatLngAlt(48.1, -12.5, 40); var q = new VV.types.LatLng(-33.9, 151.2);"
        "VV.storage.store('p', [p.lat, p.lng, p.alt, p.getLat(), p.getLng(), p.getAlt()]);"
        "VV.storage.store('q', [q.getLat(), q.getLng(), q.getAlt()]);"
    )
    run.run()
    assert run.storage == {"p": [48.1, -12.5, 40, 48.1, -12.5, 40], "q": [-33.9, 151.2, 0]}


def test_storage_store_load_list_remove() -> None:
    run = Run(
        """
        VV.storage.store('b', {x: [1, 2]});
        VV.storage.store('a', 'text');
        VV.storage.store('pos-1', 1); VV.storage.store('pos-2', 2);
        var loaded = VV.storage.load('b'); loaded.x.push(3);
        VV.storage.store('reloaded', VV.storage.load('b'));
        VV.storage.store('missing', VV.storage.load('nope') === undefined);
        VV.storage.store('all', VV.storage.list());
        VV.storage.store('pos', VV.storage.list('^pos-'));
        VV.storage.store('regexp', VV.storage.list(/^[ab]$/));
        VV.storage.remove('a');
        try { VV.storage.store('k'.repeat(129), 1); } catch (e) { VV.storage.store('long', e.name); }
        try { VV.storage.store('u', undefined); } catch (e) { VV.storage.store('undef', e.name); }
        """
    )
    assert run.run().outcome is Outcome.FINISHED
    assert run.storage["reloaded"] == {"x": [1, 2]}  # load gives a copy
    assert run.storage["missing"] is True
    assert run.storage["all"] == ["a", "b", "missing", "pos-1", "pos-2", "reloaded"]
    assert run.storage["pos"] == ["pos-1", "pos-2"]
    assert run.storage["regexp"] == ["a", "b"]
    assert "a" not in run.storage
    assert run.storage["long"] == "TypeError"
    assert run.storage["undef"] == "TypeError"


def test_log_calls_of_the_original_api() -> None:
    run = Run("VV.log('a', 1, {b: 2}); logInfo('info line'); getStdOut().println('out line');")
    run.run()
    assert run.log == ['a 1 {"b":2}', "info line", "out line"]


def test_effects_are_reported_once_across_replays() -> None:
    run = Run(PAPER_LOOP)
    run.run()
    stores = [e.key for r in run.results for e in r.effects if e.op == "store"]
    assert stores == [f"p{n}.{k}" for n in range(3) for k in range(2)]
    assert sum(len(r.effects) for r in run.results) == run.effects_applied


def test_vv_id_and_name() -> None:
    run = Run("VV.storage.store('me', [VV.id, VV.name]);")
    run.run()
    assert run.storage["me"] == ["vv-1", "VV 1"]


@pytest.mark.parametrize(
    "name",
    [
        "require",
        "process",
        "fetch",
        "setTimeout",
        "setInterval",
        "console",
        "XMLHttpRequest",
        "WebAssembly",
    ],
)
def test_nothing_but_vv_reaches_outside(name: str) -> None:
    run = Run(f"VV.storage.store('type', typeof {name});")
    run.run()
    assert run.storage["type"] == "undefined"


def test_vv_cannot_be_replaced() -> None:
    run = Run(
        "VV = null; VV.task = null; try { VV.task.execute = 1 } catch (e) {}"
        " VV.storage.store('ok', typeof VV.task.execute);"
    )
    assert run.run().outcome is Outcome.FINISHED
    assert run.storage["ok"] == "function"


def test_reserved_names_are_refused_with_their_place() -> None:
    result = Run("var x = 1;\nvar __cpcc_rethrow = 2;").run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None and result.error.line == 2
    assert "reserved" in result.error.message


def test_infinite_loop_is_killed_by_the_cpu_quota() -> None:
    result = Run("while (true) {}", limits=Limits(cpu_s=0.2)).run()
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "cpu"
    assert "CPU time" in result.error.message


def test_heap_bomb_is_killed_by_the_heap_quota() -> None:
    result = Run(
        "var a = []; while (true) { a.push(new Array(100000).fill(1.5)); }",
        limits=Limits(heap_bytes=32 * 1024 * 1024, cpu_s=20),
    ).run()
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "heap"


def test_storage_bomb_is_killed_by_the_storage_quota() -> None:
    run = Run(
        "for (var i = 0; ; i++) VV.storage.store('k' + i, 'x'.repeat(1000));",
        limits=Limits(storage_bytes=20_000),
    )
    result = run.run()
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "storage"
    assert "storage" in result.error.message
    assert 15 <= len(run.storage) <= 20  # what fitted is kept


def test_tasks_quota() -> None:
    run = Run(
        "for (var i = 0; i < 10; i++) VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3),"
        " tolerance: 1, sensors: [VV.sensor.get('GPS')]});",
        limits=Limits(max_tasks=3),
    )
    result = run.run()
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "tasks"
    assert len(run.journal) == 3


def test_a_program_that_asks_differently_on_replay_fails_as_non_deterministic() -> None:
    run = Run(PAPER_LOOP)
    run.step()
    # Pretend the journal answered a request for another point (as if the program had changed).
    pending = run.results[0].pending
    assert pending is not None
    entry = answer_task(pending, time_ms=START_MS + 1, data=[{}, {}])
    entry["r"] = entry["r"].replace("48.1111", "48.2")
    run.journal.append(entry)
    result = run.step()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None and result.error.kind is ErrorKind.NONDETERMINISM
    assert "non-determinism" in result.error.message


def test_execute_all_runs_each_callback_as_its_task_completes_and_returns_in_task_order() -> None:
    run = Run(
        """
        var gps = VV.sensor.get('GPS');
        var tasks = [];
        for (var i = 0; i < 4; i++) tasks.push({type: 'point', position: new VV.types.LatLngAlt(i, 0, 10),
                                                tolerance: 1, sensors: [gps]});
        var order = [];
        var all = VV.task.executeAll(tasks, function (data, index) { order.push(index); });
        VV.storage.store('order', order);
        VV.storage.store('values', all.map(function (d) { return d[0].value; }));
        """
    )
    assert run.run(answer=answer_with_readings).outcome is Outcome.FINISHED
    assert run.storage["order"] == [3, 2, 1, 0]  # the harness serves batches from the back
    assert run.storage["values"] == [0, 1, 2, 3]
    first = run.results[0].pending
    assert first is not None and first.kind == "batch" and first.open == (0, 1, 2, 3)


def test_bad_task_arguments_throw_type_errors_naming_the_field() -> None:
    run = Run(
        """
        var errors = [];
        try { VV.task.execute({type: 'area', position: new VV.types.LatLngAlt(1, 2, 3), sensors: []}); } catch (e) { errors.push(e.message); }
        try { VV.task.execute({type: 'point', position: null, sensors: [VV.sensor.get('GPS')]}); } catch (e) { errors.push(e.message); }
        try { VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), sensors: []}); } catch (e) { errors.push(e.message); }
        VV.storage.store('errors', errors);
        """
    )
    run.run()
    errors = run.storage["errors"]
    assert "type must be 'point'" in errors[0]
    assert "position must be" in errors[1]
    assert "sensors must be a non-empty array" in errors[2]
