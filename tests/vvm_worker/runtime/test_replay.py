"""Replay in a warm context: each run gets exactly what a run in a new context would get.

A warm context keeps the journal's readings parsed and the requests they answer, and hands each
run its own copy of the readings; these tests pin down that nothing of that can be observed.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

from tests.vvm_worker.runtime.harness import (
    CATALOG,
    START_MS,
    Answer,
    Run,
    answer_with_readings,
)
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    Runtime,
    StepInput,
    StepResult,
    answer_part,
    answer_task,
)

GPS_TASK = (
    "{type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]}"
)


def warm_run(
    source: str,
    *,
    answer: Answer = answer_with_readings,
    runtime: Runtime | None = None,
    edit: Callable[[dict[str, Any]], None] | None = None,
    seed: Callable[[int], int] = lambda n: 3,
) -> tuple[StepResult, dict[str, Any], Runtime]:
    """Step a VV to its end in one warm context; its last result and its storage.

    ``edit`` changes each journal entry before the next step sees it (as a host would that
    recorded it differently); ``seed`` gives the seed of the n-th step (a host gives the same
    one to every step: another seed makes the program ask for something else).
    """
    runtime = runtime or Runtime()
    journal: list[dict[str, Any]] = []
    storage: dict[str, Any] = {}
    applied = 0
    for n in range(50):
        step = StepInput(
            vv_id="vv-a",
            vv_name="vv-a",
            source=source,
            seed=seed(n),
            start_ms=START_MS,
            catalog=CATALOG,
            journal=list(journal),
            effects_applied=applied,
        )
        result = runtime.step(step)
        for e in result.effects:
            assert e.seq >= applied, "an effect was reported twice"
            if e.op == "store" and e.key is not None and e.value_json is not None:
                storage[e.key] = json.loads(e.value_json)
        applied = max(applied, result.effects_total)
        if result.outcome is not Outcome.SUSPENDED:
            return result, storage, runtime
        assert result.pending is not None
        entry = answer(result.pending, START_MS + 1000 * (n + 1))
        if edit is not None:
            edit(entry)
        journal.append(entry)
    raise AssertionError("the program did not end")


def answer_with(data: list[Any]) -> Answer:
    def answer(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        return answer_task(pending, time_ms=time_ms, data=data)

    return answer


def test_a_program_that_changes_its_readings_gets_them_unchanged_in_the_next_run() -> None:
    source = f"""
    var first = VV.task.execute({GPS_TASK});
    var seen = JSON.stringify(first);
    first[0].value = 'changed';
    first[0].position.lat = -1;
    delete first[0].sensor;
    first.push('extra');
    VV.task.execute({GPS_TASK}, function (data) {{ data[0].value = 'changed too'; }});
    for (var i = 0; i < 3; i++) VV.task.execute({GPS_TASK});
    VV.storage.store('seen', seen);
    """
    reading = {"sensor": "GPS", "position": {"lat": 1, "lng": 2, "alt": 3}, "value": 7}
    result, storage, _ = warm_run(source, answer=answer_with([reading]))
    assert result.outcome is Outcome.FINISHED, result.error
    # The last run replayed the first answer five times before: it still got the journal's
    # reading.
    assert json.loads(storage["seen"]) == [reading]


def test_readings_keep_every_detail_their_json_gives() -> None:
    source = f"""
    var d = VV.task.execute({GPS_TASK})[0];
    var descriptors = Object.getOwnPropertyDescriptors(d);
    var report = {{
      keys: Object.keys(d),
      plain: Object.getPrototypeOf(d) === Object.prototype,
      ownProto: Object.prototype.hasOwnProperty.call(d, '__proto__'),
      protoValue: d['__proto__'],
      toString: d.toString,
      constructor: d.constructor,
      negativeZeroIsZero: Object.is(d.neg, 0),
      allPlainData: Object.keys(descriptors).every(function (k) {{
        var p = descriptors[k];
        return p.writable && p.enumerable && p.configurable && 'value' in p;
      }}),
      arrays: Array.isArray(d.nested) && Array.isArray(d.nested[0][1]),
      text: JSON.stringify(d),
    }};
    VV.task.execute({GPS_TASK});
    VV.task.execute({GPS_TASK});
    VV.storage.store('report', report);
    """
    reading = {
        "toString": "t",
        "__proto__": {"x": 1},
        "constructor": 5,
        "2": "b",
        "1": "a",
        "nested": [[1, [2]], {"e": None}],
        "flag": True,
        "neg": -0.0,
        "big": 1e300,
        "text": "é ✓ \u2028",
    }
    result, storage, _ = warm_run(source, answer=answer_with([reading]))
    assert result.outcome is Outcome.FINISHED, result.error
    report = storage["report"]
    assert report["keys"] == sorted(reading)  # the host writes entries with their keys sorted
    assert report["plain"] and report["ownProto"] and report["allPlainData"] and report["arrays"]
    assert (report["protoValue"], report["toString"], report["constructor"]) == ({"x": 1}, "t", 5)
    assert report["negativeZeroIsZero"]
    assert json.loads(report["text"]) == {**reading, "neg": 0}


def test_deeply_nested_readings_reach_every_run_unchanged() -> None:
    deep: Any = "leaf"
    for _ in range(40):
        deep = {"d": [deep]}
    source = f"""
    var node = VV.task.execute({GPS_TASK})[0];
    var depth = 0;
    while (typeof node === 'object') {{ node = node.d[0]; depth++; }}
    var again = VV.task.execute({GPS_TASK})[0];
    again.d = null;
    VV.task.execute({GPS_TASK});
    VV.storage.store('found', [depth, node]);
    """
    result, storage, _ = warm_run(source, answer=answer_with([deep]))
    assert result.outcome is Outcome.FINISHED, result.error
    assert storage["found"] == [40, "leaf"]


def test_a_request_that_differs_in_any_field_from_the_journals_is_non_deterministic() -> None:
    source = f"VV.task.execute({GPS_TASK}); VV.task.execute({GPS_TASK});"
    recorded = json.dumps(
        {
            "type": "point",
            "position": {"lat": 1, "lng": 2, "alt": 3},
            "tolerance": 1,
            "sensors": ["GPS"],
        },
        separators=(",", ":"),
    )
    changes = [
        recorded.replace('"tolerance":1', '"tolerance":2'),
        recorded.replace('"alt":3', '"alt":3.5'),
        recorded.replace('["GPS"]', '["GPS","GPS"]'),
        recorded.replace('"lat":1,"lng":2', '"lng":2,"lat":1'),  # the same values, other order
        json.dumps(json.loads(recorded)),  # the same values, other spacing
    ]
    unchanged, _, _ = warm_run(source)
    assert unchanged.outcome is Outcome.FINISHED, unchanged.error
    for changed in changes:

        def edit(entry: dict[str, Any], changed: str = changed) -> None:
            assert entry["r"] == recorded
            entry["r"] = changed

        result, _, _ = warm_run(source, edit=edit)
        assert result.outcome is Outcome.FAILED, changed
        assert result.error is not None and result.error.kind is ErrorKind.NONDETERMINISM
        assert "journal holds " + changed in result.error.message


def test_a_request_that_changes_after_it_was_answered_is_non_deterministic() -> None:
    # Another seed from the fourth step on moves the points: by then each answer was compared
    # with its request at least once before, which the context keeps parsed.
    task = GPS_TASK.replace("LatLngAlt(1, 2, 3)", "LatLngAlt(Math.random(), 2, 3)")
    other = task.replace("tolerance: 1", "tolerance: 5")
    sources = [
        f"for (var i = 0; i < 5; i++) VV.task.execute({task});",
        f"VV.task.executeAll([{task}, {other}]); VV.task.execute({task}); VV.task.execute({task});",
    ]

    def answer(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        if pending.kind == "batch":
            i = pending.open[0]
            return answer_part(pending, index=i, time_ms=time_ms, data=[{"value": i}])
        return answer_task(pending, time_ms=time_ms, data=[])

    for source in sources:
        same, _, _ = warm_run(source, answer=answer)
        assert same.outcome is Outcome.FINISHED, same.error
        result, _, _ = warm_run(source, answer=answer, seed=lambda n: 3 if n < 3 else 4)
        assert result.outcome is Outcome.FAILED, source
        assert result.error is not None and result.error.kind is ErrorKind.NONDETERMINISM
        assert "request #1" in result.error.message


def test_a_value_stored_again_under_a_key_reads_back_as_stored_at_that_point() -> None:
    source = f"""
    VV.storage.store('k', {{n: 1}});
    var first = VV.storage.load('k');
    VV.storage.store('k', {{n: 2}});
    VV.task.execute({GPS_TASK});
    VV.task.execute({GPS_TASK});
    VV.storage.store('seen', [first, VV.storage.load('k')]);
    """
    result, storage, _ = warm_run(source)
    assert result.outcome is Outcome.FINISHED, result.error
    assert storage["seen"] == [{"n": 1}, {"n": 2}]


def test_answers_of_any_size_reach_a_warm_context() -> None:
    big = "x" * 200_000  # more than a step carries with it: appended in a call of its own
    source = f"""
    var sizes = [];
    for (var i = 0; i < 4; i++) sizes.push(VV.task.execute({GPS_TASK})[0].length);
    VV.storage.store('sizes', sizes);
    """

    def answer(pending: PendingRequest, time_ms: int) -> dict[str, Any]:
        return answer_task(pending, time_ms=time_ms, data=[big if pending.q % 2 else "small"])

    runtime = Runtime()
    result, storage, _ = warm_run(source, answer=answer, runtime=runtime)
    assert result.outcome is Outcome.FINISHED, result.error
    assert storage["sizes"] == [5, 200_000, 5, 200_000]
    fresh = Run(source)
    fresh.run(answer=answer)
    assert fresh.storage["sizes"] == storage["sizes"]


def test_a_warm_context_has_every_answer_it_was_sent() -> None:
    source = f"for (var i = 0; i < 3; i++) VV.task.execute({GPS_TASK});"
    runtime = Runtime()
    journal: list[dict[str, Any]] = []
    first = None
    for n in range(3):
        step = StepInput(
            vv_id="vv-a",
            vv_name="vv-a",
            source=source,
            seed=3,
            start_ms=START_MS,
            catalog=CATALOG,
            journal=list(journal),
        )
        result = runtime.step(step)
        assert result.outcome is Outcome.SUSPENDED and result.pending is not None
        ctx = runtime.context("vv-a")
        assert ctx is not None and ctx.journal_length == n
        first = first or ctx
        assert ctx is first
        journal.append(answer_with_readings(result.pending, START_MS + n))
