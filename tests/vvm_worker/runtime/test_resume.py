"""A warm context resumes a program where it waits instead of re-running it (issue 13).

A program whose waiting calls are in its own body is compiled as a generator: between steps it
stays suspended at the call, and the next step reads only the new answer. These tests show it
by what each step reads from the journal (``answers_read``), and that nothing else changes:
the same effects, requests and storage as replaying every step in a new context, and replay
whenever resuming would not be exact (effects the host did not apply, other limits, a call the
platform could not turn into a suspension point).
"""

from __future__ import annotations

import json
from dataclasses import replace
from typing import Any

import pytest

from tests.vvm_worker.runtime.harness import (
    CATALOG,
    START_MS,
    Answer,
    Run,
    answer_with_readings,
    reject_all,
)
from vvm_worker.runtime import (
    Limits,
    Outcome,
    Runtime,
    StepInput,
    StepResult,
)
from vvm_worker.runtime.instrument import Instrumented, instrument_program

GPS_TASK = (
    "{type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]}"
)

LOOP = f"""
var seen = 0;
for (var k = 0; k < 60; k++) {{
  VV.task.execute({GPS_TASK}, function (data) {{
    seen++;
    VV.storage.store('pos-' + k, data[0].value);
  }});
}}
VV.storage.store('seen', seen);
"""


def step_input(source: str, journal: list[dict[str, Any]], applied: int, **kw: Any) -> StepInput:
    return StepInput(
        vv_id="vv-r",
        vv_name="vv-r",
        source=source,
        seed=5,
        start_ms=START_MS,
        catalog=CATALOG,
        journal=list(journal),
        effects_applied=applied,
        **kw,
    )


class Host:
    """One warm runtime stepping one VV, applying effects as the VVM does."""

    def __init__(self, source: str, *, answer: Answer = answer_with_readings) -> None:
        self.source = source
        self.answer = answer
        self.runtime = Runtime()
        self.journal: list[dict[str, Any]] = []
        self.applied = 0
        self.storage: dict[str, Any] = {}
        self.log: list[str] = []
        self.results: list[StepResult] = []

    def step(self, **kw: Any) -> StepResult:
        result = self.runtime.step(step_input(self.source, self.journal, self.applied, **kw))
        for e in result.effects:
            assert e.seq >= self.applied, "an effect was reported twice"
            if e.op == "store":
                self.storage[e.key] = json.loads(e.value_json)
            elif e.op == "log":
                self.log.append(e.message)
        self.applied = max(self.applied, result.effects_total)
        self.results.append(result)
        if result.outcome is Outcome.SUSPENDED:
            assert result.pending is not None
            self.journal.append(
                self.answer(result.pending, START_MS + 1000 * (len(self.journal) + 1))
            )
        return result

    def run(self) -> StepResult:
        while True:
            result = self.step()
            if result.outcome is not Outcome.SUSPENDED:
                return result


def observed(results: list[StepResult]) -> list[tuple[Any, ...]]:
    """What the VVM takes from each step: outcome, pending request, effects, requests, storage."""
    return [
        (r.outcome, r.pending, r.effects, r.effects_total, r.requests, r.storage_bytes)
        for r in results
    ]


def test_a_warm_step_reads_only_its_new_answer_however_long_the_journal() -> None:
    host = Host(LOOP)
    last = host.run()
    assert last.outcome is Outcome.FINISHED, last.error
    reads = [r.answers_read for r in host.results]
    # The first step reads nothing; each later one only the answer it was waiting for, the
    # 50th as the 5th (a replay would read 49 there).
    assert reads == [0] + [1] * 60
    assert host.storage["seen"] == 60
    assert host.storage["pos-49"] == 49


def test_resuming_gives_what_replaying_every_step_in_a_new_context_gives() -> None:
    host = Host(LOOP)
    host.run()
    replayed = Run(LOOP, seed=5)
    cold = replayed.run()
    assert cold.outcome is Outcome.FINISHED
    # run_step makes a new context for every step: it re-runs the program from its start.
    assert [r.answers_read for r in replayed.results][:5] == [0, 1, 2, 3, 4]
    assert host.storage == replayed.storage
    assert observed(host.results) == observed(replayed.results)


def test_a_vv_that_moves_replays_once_on_its_new_host_then_resumes_there() -> None:
    host = Host(LOOP)
    for _ in range(30):
        host.step()
    assert host.results[-1].answers_read == 1
    host.runtime.close()
    host.runtime = Runtime()  # another host: a new context from the checkpoint
    arrived = host.step()
    assert arrived.answers_read == 30
    assert host.step().answers_read == 1
    assert host.run().outcome is Outcome.FINISHED
    assert host.storage["seen"] == 60


def test_a_vv_that_comes_back_catches_up_in_the_context_it_left_instead_of_replaying() -> None:
    """Between two hosts (two worker processes) and back: the context the VV left reads the
    answers of the steps made elsewhere, does their effects again unreported and goes on,
    with the same effects, requests and storage as replaying every step in a new context."""
    host = Host(LOOP)
    here, there = host.runtime, Runtime()
    reads = []
    for k in range(60):
        host.runtime = here if (k // 3) % 2 == 0 else there  # three steps each, back and forth
        reads.append(host.step().answers_read)
    assert host.run().outcome is Outcome.FINISHED
    # Back on a host it left three steps ago: the three answers of the steps made elsewhere
    # and the one it waits for (a replay would read them all: 7, 10, ...). The second host's
    # first step is a replay in a new context (3).
    assert reads[:10] == [0, 1, 1, 3, 1, 1, 4, 1, 1, 4]
    assert max(reads[6:]) == 4
    assert not any(r.replayed for r in host.results[6:])
    replayed = Run(LOOP, seed=5)
    replayed.run()
    assert host.storage == replayed.storage
    assert observed(host.results) == observed(replayed.results)


def test_effects_the_host_did_not_apply_are_reported_again_by_a_replay() -> None:
    host = Host(LOOP)
    for _ in range(10):
        host.step()
    lost = host.results[-1]
    assert lost.effects  # the callback's write of the last answer
    # The host lost that step's effects (its transaction rolled back) and steps again.
    host.applied -= len(lost.effects)
    host.journal.pop()
    again = host.step()
    assert again.answers_read == 9  # re-ran from the start
    assert again.effects == lost.effects
    assert host.step().answers_read == 1
    assert host.run().outcome is Outcome.FINISHED
    assert host.storage["seen"] == 60


def test_other_limits_make_the_next_step_a_replay() -> None:
    host = Host(LOOP)
    for _ in range(10):
        host.step()
    result = host.step(limits=Limits(max_tasks=5))
    assert result.answers_read == 5  # re-ran from the start, killed at its 6th task
    assert result.outcome is Outcome.KILLED
    assert result.error is not None and result.error.quota == "tasks"


def test_globals_a_program_makes_and_finally_clauses_behave_as_in_a_blocking_program() -> None:
    source = f"""
    count = 0;  // an implicit global: it lives as long as the program runs
    for (var k = 0; k < 5; k++) {{
      try {{
        VV.task.execute({GPS_TASK}, function () {{ count++; }});
      }} finally {{
        VV.log('after ' + k + ': ' + count);
      }}
    }}
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 1, 1, 1, 1]
    # Each finally ran once, after its call returned; never while the program waited.
    assert host.log == [f"after {k}: {k + 1}" for k in range(5)]


def test_a_rejected_task_is_thrown_where_the_program_waits() -> None:
    source = f"""
    var tries = 0;
    while (true) {{
      tries++;
      try {{ VV.task.execute({GPS_TASK}); break; }}
      catch (e) {{ if (!(e instanceof VV.errors.TaskRejectedError) || tries > 2) throw e; }}
    }}
    """
    host = Host(source, answer=reject_all("no vehicle can serve it"))
    result = host.run()
    assert result.outcome is Outcome.FAILED
    assert result.error is not None
    assert "TaskRejectedError: no vehicle can serve it" in result.error.message
    line = source.split("\n")[5]
    assert (result.error.line, result.error.column) == (6, line.index("throw e") + 1)
    assert [r.answers_read for r in host.results] == [0, 1, 1, 1]


def test_an_error_on_the_line_of_a_resumed_call_has_the_users_column() -> None:
    source = f"var d = VV.task.execute({GPS_TASK}, function (data) {{ null.x; }});\n"
    host = Host(source)
    result = host.run()
    assert result.outcome is Outcome.FAILED and result.error is not None
    assert result.error.message.startswith("TypeError: Cannot read properties of null")
    assert (result.error.line, result.error.column) == (1, source.index("null.x") + 6)


@pytest.mark.parametrize(
    "source",
    [
        # A call in a function the program uses as a value cannot wait by yielding: replay.
        f"var visit = function () {{ return VV.task.execute({GPS_TASK}); }};\n"
        "for (var k = 0; k < 6; k++) visit();",
        f"function visit() {{ return VV.task.execute({GPS_TASK}); }}\n"
        "for (var k = 0; k < 6; k++) [k].forEach(visit);",
        f"function visit() {{ return VV.task.execute({GPS_TASK}) + arguments.length; }}\n"
        "for (var k = 0; k < 6; k++) visit();",
        # VV is another object here (as far as the platform can tell): left as written.
        f"var VV2 = VV; for (var k = 0; k < 6; k++) VV2.task.execute({GPS_TASK});",
    ],
)
def test_calls_the_platform_cannot_suspend_still_work_by_replay(source: str) -> None:
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 2, 3, 4, 5, 6]


def test_a_program_mixing_both_kinds_of_call_replays_only_after_the_other_kind() -> None:
    source = f"""
    var inner = function () {{ return VV.task.execute({GPS_TASK}); }};
    for (var k = 0; k < 3; k++) {{ VV.task.execute({GPS_TASK}); inner(); }}
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    # Waiting in inner() ends the run (replay next time); waiting in the loop keeps it.
    assert [r.answers_read for r in host.results] == [0, 1, 2, 1, 4, 1, 6]


@pytest.mark.parametrize(
    ("source", "generator"),
    [
        ("VV.task.execute(t);", True),
        ("VV.task.executeAll([t], function (d, i) {});", True),
        ("if (a) { while (b) { x = [VV.task.execute(t)]; } }", True),
        ("var f = function () { VV.task.execute(t); };", False),
        ("function f() { VV.task.execute(t); } f();", True),
        ("function f() { VV.task.execute(t); } [1].forEach(f);", False),
        ("function f() { VV.task.execute(t); } var g = function () { f(); };", False),
        ("function f() { return g(); } function g() { VV.task.execute(t); } f();", True),
        ("function f() { VV.task.execute(t); } function f() {} f();", False),
        ("function f() { VV.task.execute(t); return arguments; } f();", False),
        ("async function f() { VV.task.execute(t); } f();", False),
        ("var f = () => VV.task.execute(t);", False),
        ("class A { m() { VV.task.execute(t); } }", False),
        ("var VV = {task: {execute: function () {}}}; VV.task.execute(t);", False),
        ("var o = {VV}; VV.task.execute(t);", False),
        ("with (o) { VV.task.execute(t); }", False),
        ("var yield = 1; VV.task.execute(t);", False),
        ("VV.task.execute?.(t);", False),
        ("var t = VV.task; t.execute(t);", False),
    ],
)
def test_the_program_is_made_a_generator_only_where_nothing_can_tell(
    source: str, generator: bool
) -> None:
    assert instrument_program(source).generator is generator


def test_a_moved_call_keeps_its_users_column() -> None:
    done = instrument_program("x(); VV.task.execute(t, function () { y(); });")
    assert done.code == "x(); (yield* __cpcc_execute(t, function () { y(); }));"
    assert done.user_column(1, done.code.index("y()") + 1) == 39
    assert done.user_column(1, done.code.index("__cpcc_execute") + 1) == 14  # at "execute"
    assert done.user_column(1, 3) == 3


def test_a_replay_after_a_resumed_program_left_an_undeletable_global_runs_in_a_new_context() -> (
    None
):
    source = f"""
    VV.storage.store('start', typeof marker === 'undefined' ? 'clean' : 'seen before');
    Object.defineProperty(globalThis, 'marker', {{value: 1, configurable: false}});
    for (var k = 0; k < 3; k++) VV.task.execute({GPS_TASK});
    """
    host = Host(source)
    host.step()
    assert host.step().answers_read == 1  # resumed: the global stays, as in a blocking program
    # The host lost the step's effects: the replay must not see the marker.
    host.applied = 0
    host.storage.clear()
    again = host.step()
    assert again.answers_read == 2
    assert host.storage == {"start": "clean"}
    assert host.run().outcome is Outcome.FINISHED


def test_a_program_cannot_take_over_its_own_resumption() -> None:
    # The program's own function is a generator: what it could put on its prototype would be
    # what the platform calls to resume it.
    source = f"""
    var me = arguments.callee, refused = [];
    try {{
      Object.defineProperty(me.prototype, 'next', {{
        value: function () {{ return {{done: true, value: undefined}}; }},
      }});
    }} catch (e) {{ refused.push(e.name); }}
    for (var k = 0; k < 4; k++) VV.task.execute({GPS_TASK});
    VV.storage.store('done', [k, refused]);
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 1, 1, 1]
    assert host.storage == {"done": [4, ["TypeError"]]}


def test_nothing_is_kept_on_the_programs_function_from_one_run_to_the_next() -> None:
    # Replayed at every step (the call is in a function): each run must start as the first.
    source = f"""
    var me = arguments.callee;
    me.runs = (me.runs || 0) + 1;
    var visit = function () {{ return VV.task.execute({GPS_TASK}); }};
    for (var k = 0; k < 3; k++) {{ visit(); VV.storage.store('runs ' + k, me.runs || 0); }}
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 2, 3]
    assert host.storage == {"runs 0": 0, "runs 1": 0, "runs 2": 0}


def test_nothing_is_kept_on_the_platforms_hooks_from_one_run_to_the_next() -> None:
    source = f"""
    var kept = [];
    ['rethrow', 'suspended', 'execute', 'executeAll', 'host'].forEach(function (name) {{
      var hook = globalThis['__cp' + 'cc_' + name];
      var o = name === 'host' ? hook.step : hook;
      if (o.runs) kept.push(name);
      try {{ o.runs = 1; }} catch (e) {{}}
    }});
    var visit = function () {{ return VV.task.execute({GPS_TASK}); }};
    for (var k = 0; k < 2; k++) {{ visit(); VV.storage.store('kept ' + k, kept); }}
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert host.storage == {"kept 0": [], "kept 1": []}


def test_a_batch_resumes_at_each_of_its_parts() -> None:
    source = f"""
    for (var round = 0; round < 2; round++) {{
      var got = VV.task.executeAll([{GPS_TASK}, {GPS_TASK}, {GPS_TASK}], function (d, i) {{
        VV.storage.store(round + '.' + i, d[0].value);
      }});
      VV.storage.store('round ' + round, got.length);
    }}
    """
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0, 1, 1, 1, 1, 1, 1]
    replayed = Run(source, seed=5)
    assert replayed.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in replayed.results] == [0, 1, 2, 3, 4, 5, 6]
    assert host.storage == replayed.storage
    assert host.storage["round 1"] == 3 and len(host.storage) == 8


def test_a_function_of_the_program_that_waits_resumes_too() -> None:
    source = f"""
    function one() {{
      return VV.task.execute({GPS_TASK})[0].value;
    }}
    function reading(k, seen) {{
      var total = one();
      for (var j = 0; j < k; j++) total += one();  // a helper calling a helper
      return total;
    }}
    function survey(n) {{
      var total = 0;
      for (var i = 0; i < n; i++) total += reading(1, 0);
      return total;
    }}
    VV.storage.store('total', survey(3));
    VV.storage.store('single', reading(0, 0));
    """
    code = instrument_program(source).code
    assert "function* survey" in code and "function* reading" in code and "function* one" in code
    host = Host(source)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results] == [0] + [1] * 7
    replayed = Run(source, seed=5)
    assert replayed.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in replayed.results] == list(range(8))
    assert host.storage == replayed.storage == {"total": sum(range(6)), "single": 6}


def test_a_program_v8_refuses_as_a_generator_runs_the_replay_way(monkeypatch) -> None:
    from vvm_worker.runtime import context

    def broken(source: str, *, suspendable: bool = True) -> Instrumented:
        done = instrument_program(source, suspendable=suspendable)
        if done.generator:  # as if the rewrite had made code V8 cannot parse
            return replace(done, code=done.code + "\n)")
        return done

    monkeypatch.setattr(context, "instrument_program", broken)
    host = Host(LOOP)
    assert host.run().outcome is Outcome.FINISHED
    assert [r.answers_read for r in host.results][:4] == [0, 1, 2, 3]
    assert host.storage["seen"] == 60


def test_a_call_v8_stops_before_the_program_takes_its_answer_is_replayed_not_taken_as_done(
    monkeypatch,
) -> None:
    """When V8 fails the call of a step before the program took the answer it was given (an
    isolate a step left with its heap over the limit, say), the outcome the context still
    holds is the earlier step's: the step must not be taken from it (the VV would ask for the
    task it was just given again), but run again in a new context, which replays it."""
    from vvm_worker.runtime import context as context_module
    from vvm_worker.runtime.v8 import JSEvalException

    host = Host(LOOP)
    first = host.step()
    assert first.outcome is Outcome.SUSPENDED and first.pending.q == 0
    broken = host.runtime.context("vv-r")
    assert broken is not None
    real = context_module.VVContext._host

    def failing(self, call: str, *args: str, **kw: Any) -> Any:
        if self is broken and call in ("stepIfResumes", "step"):
            raise JSEvalException("null")
        return real(self, call, *args, **kw)

    monkeypatch.setattr(context_module.VVContext, "_host", failing)
    second = host.step()
    assert second.outcome is Outcome.SUSPENDED and second.pending.q == 1
    assert second.replayed and second.answers_read == 1  # in a new context
    assert host.runtime.context("vv-r") is not broken
    assert host.storage == {"pos-0": 0}
