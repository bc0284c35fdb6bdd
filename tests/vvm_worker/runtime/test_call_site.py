"""Where in the program each request is made (a dry run's line and column per task), and where
a quota stopped it: the same in a warm context and on replay, and invisible to the program."""

from __future__ import annotations

import pytest

from tests.vvm_worker.runtime.harness import CATALOG, START_MS, answer_with_readings
from vvm_worker.runtime import Limits, Outcome, Runtime, StepInput, StepResult

PROGRAM = """var gps = VV.sensor.get('GPS');
var t = function (n) { return {position: new VV.types.LatLngAlt(n, 2, 30), sensors: [gps]}; };
for (var i = 0; i < 2; i++) {
  VV.task.execute(t(i));
}
[5].forEach(function (n) { VV.task.execute(t(n)); });
  VV.task.executeAll([t(6), t(7)]);
/(b)/.exec('abc'); VV.task.execute(t(8)); VV.log(RegExp.$1, RegExp.lastMatch);
"""


def _column(line: int, text: str, nth: int = 0) -> int:
    source = PROGRAM.splitlines()[line - 1]
    at = -1
    for _ in range(nth + 1):
        at = source.index(text, at + 1)
    return at + 1


def _steps(runtime: Runtime, limits: Limits) -> list[StepResult]:
    journal: list[dict] = []
    results = []
    for k in range(20):
        result = runtime.step(
            StepInput(
                vv_id="vv-1",
                vv_name="VV 1",
                source=PROGRAM,
                seed=7,
                start_ms=START_MS,
                catalog=CATALOG,
                journal=journal,
                limits=limits,
            )
        )
        results.append(result)
        if result.pending is None:
            return results
        journal.append(answer_with_readings(result.pending, START_MS + 1000 * (k + 1)))
    raise AssertionError("the program did not end")


@pytest.mark.parametrize("warm", [True, False], ids=["warm", "replayed"])
def test_each_request_says_where_the_program_made_it(warm: bool) -> None:
    results = _steps(Runtime(max_contexts=4 if warm else 0), Limits())
    places = [(r.pending.q, r.pending.line, r.pending.column) for r in results if r.pending]
    execute = _column(4, "execute")
    assert places == [
        (0, 4, execute),
        (1, 4, execute),
        (2, 6, _column(6, "execute")),  # in a callback: where the callback calls
        (3, 7, _column(7, "executeAll")),
        (3, 7, _column(7, "executeAll")),  # the batch's second part: the same call
        (4, 8, _column(8, "execute")),
    ]
    # Finding the place leaves nothing the program sees (RegExp's legacy statics included).
    assert results[-1].outcome is Outcome.FINISHED
    (log,) = [e.message for r in results for e in r.effects if e.op == "log"]
    assert log == "b b"


@pytest.mark.parametrize("warm", [True, False], ids=["warm", "replayed"])
def test_a_quota_kill_says_where(warm: bool) -> None:
    results = _steps(Runtime(max_contexts=4 if warm else 0), Limits(max_tasks=3))
    last = results[-1]
    assert last.outcome is Outcome.KILLED and last.error is not None
    assert last.error.quota == "tasks"
    assert (last.error.line, last.error.column) == (7, _column(7, "executeAll"))
