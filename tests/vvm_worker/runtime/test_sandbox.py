"""The sandbox: only VV and standard ECMAScript; tampering stays inside one run of one VV."""

from __future__ import annotations

import json

import pytest

from tests.vvm_worker.runtime.harness import CATALOG, START_MS, Run, answer_with_readings
from vvm_worker.runtime import Outcome, Runtime, StepInput

GPS_TASK = (
    "{type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]}"
)


@pytest.mark.parametrize(
    "name", ["WeakRef", "FinalizationRegistry", "Intl", "Temporal", "Atomics", "SharedArrayBuffer"]
)
def test_what_could_observe_the_host_is_gone(name: str) -> None:
    run = Run(f"VV.storage.store('type', typeof {name});")
    run.run()
    assert run.storage["type"] == "undefined"


@pytest.mark.parametrize(
    "code",
    ["eval('1 + 1')", "new Function('return 1')()", "(function () {}).constructor('return 1')()"],
)
def test_code_generation_from_strings_is_refused(code: str) -> None:
    run = Run(
        f"try {{ {code}; VV.storage.store('ran', true); }} catch (e) {{ VV.storage.store('error', e.name + ': ' + e.message); }}"
    )
    run.run()
    assert "ran" not in run.storage
    assert run.storage["error"].startswith("EvalError: Code generation from strings disallowed")


def test_built_ins_cannot_be_changed_and_ordinary_overrides_still_work() -> None:
    run = Run(
        """
        Array.prototype.push = function () { return 'hacked'; };
        Object.prototype.polluted = 1;
        JSON.parse = null;
        Math.random = function () { return 0; };
        class MyError extends Error { constructor(m) { super(m); this.name = 'MyError'; } }
        function Point(x) { this.x = x; }
        Point.prototype.toString = function () { return 'P' + this.x; };
        var a = []; a.push(1);
        VV.storage.store('results', [a.length, ({}).polluted === undefined, typeof JSON.parse,
                                     Math.random() !== 0, new MyError('m').name, String(new Point(3))]);
        """
    )
    assert run.run().outcome is Outcome.FINISHED
    assert run.storage["results"] == [1, True, "function", True, "MyError", "P3"]


def step_input(
    source: str, journal: list, applied: int, vv_id: str = "vv-a", seed: int = 3
) -> StepInput:
    return StepInput(
        vv_id=vv_id,
        vv_name=vv_id,
        source=source,
        seed=seed,
        start_ms=START_MS,
        catalog=CATALOG,
        journal=list(journal),
        effects_applied=applied,
    )


def drive(runtime: Runtime, source: str, vv_id: str) -> tuple[list, dict]:
    """Step a VV to its end in one runtime; returns its journal and storage."""
    journal: list = []
    storage: dict = {}
    applied = 0
    for n in range(50):
        result = runtime.step(step_input(source, journal, applied, vv_id))
        for e in result.effects:
            if e.op == "store":
                storage[e.key] = e.value_json
        applied = result.effects_total
        if result.outcome is not Outcome.SUSPENDED:
            assert result.outcome is Outcome.FINISHED, result.error
            return journal, storage
        assert result.pending is not None
        journal.append(answer_with_readings(result.pending, START_MS + n))
    raise AssertionError("did not end")


IMPLICIT = f"""
if (typeof counter === 'undefined') counter = 0;
counter++;
globalThis.extra = (globalThis.extra || 0) + 1;
var values = [];
for (var i = 0; i < 3; i++) {{
  VV.task.execute({GPS_TASK});
  values.push([counter, extra, Math.random()]);
}}
VV.storage.store('values', values);
"""


def test_a_warm_context_runs_each_step_as_a_fresh_one_would() -> None:
    warm = Runtime()
    _, storage = drive(warm, IMPLICIT, "vv-a")
    fresh = Run(IMPLICIT, seed=3)  # a new context for every step
    fresh.run()
    values = json.loads(storage["values"])
    assert [v[:2] for v in values] == [
        [1, 1],
        [1, 1],
        [1, 1],
    ]  # implicit globals do not survive a run
    assert values == fresh.storage["values"]


def test_the_runtime_keeps_one_warm_context_per_vv_and_forgets_it_on_request() -> None:
    runtime = Runtime()
    source = f"VV.task.execute({GPS_TASK}); VV.task.execute({GPS_TASK});"
    first = runtime.step(step_input(source, [], 0))
    ctx = runtime.context("vv-a")
    assert ctx is not None and ctx.journal_length == 0
    assert first.pending is not None
    journal = [answer_with_readings(first.pending, START_MS)]
    runtime.step(step_input(source, journal, 0))
    assert runtime.context("vv-a") is ctx and ctx.journal_length == 1
    runtime.forget("vv-a")
    assert runtime.context("vv-a") is None and len(runtime) == 0


def test_a_context_whose_journal_was_rolled_back_is_not_reused() -> None:
    runtime = Runtime()
    source = f"var d = VV.task.execute({GPS_TASK}); VV.storage.store('v', d[0].value); VV.task.execute({GPS_TASK});"
    first = runtime.step(step_input(source, [], 0))
    assert first.pending is not None
    answered = answer_with_readings(first.pending, START_MS)
    runtime.step(step_input(source, [answered], 0))
    old = runtime.context("vv-a")
    # The answer was never committed; the task was served again with another reading.
    again = dict(answered, data=[dict(answered["data"][0], value=42)])
    result = runtime.step(step_input(source, [again], 0))
    assert runtime.context("vv-a") is not old
    assert [(e.key, e.value_json) for e in result.effects] == [("v", "42")]


def test_tampering_in_one_vv_does_not_reach_another_in_the_same_runtime() -> None:
    runtime = Runtime()
    tamper = f"""
    try {{ Object.defineProperty(Array.prototype, 'push', {{value: null}}); }} catch (e) {{}}
    try {{ Object.setPrototypeOf(Object.prototype, {{evil: true}}); }} catch (e) {{}}
    evilGlobal = true;
    VV.task.execute({GPS_TASK});
    """
    drive(runtime, tamper, "vv-bad")
    _, storage = drive(runtime, IMPLICIT, "vv-good")
    assert storage["values"].startswith("[[1,1,")


def test_an_undeletable_global_makes_the_context_unusable_but_not_the_vv() -> None:
    runtime = Runtime()
    source = f"""
    Object.defineProperty(globalThis, 'sticky', {{value: (globalThis.sticky || 0) + 1, configurable: false}});
    VV.task.execute({GPS_TASK});
    VV.storage.store('sticky', sticky);
    """
    _, storage = drive(runtime, source, "vv-sticky")
    assert storage == {"sticky": "1"}
    assert runtime.context("vv-sticky") is None
