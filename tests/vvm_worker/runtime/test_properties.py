"""Property: the rewrite that makes a program suspendable changes nothing it can observe.

Programs are drawn from a small grammar of statements around waiting calls: sequences, ``for``
loops with a counter, ``if`` on a reading or on ``Math.random()``, ``try``/``catch``/``finally``
around waiting calls (catch with a name, a pattern or no binding), helper functions declared at
the top level that wait, callbacks that store, ``VV.log``, ``VV.storage.store`` with computed
keys, and the semicolon at a line's end sometimes left out. Each program runs resumed in one
warm context, replayed in a new context at every step, moved back and forth between two hosts
that keep its context (catching up there), and as written (not made suspendable); every
request is answered with the harness's readings, or some rejected. All four must end the
same: outcome, error (message, line and column), storage, log and the requests made.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.vvm_worker.runtime.harness import Answer, answer_with_readings
from tests.vvm_worker.runtime.test_rewrite_soundness import drive
from vvm_worker.runtime import PendingRequest, answer_reject

TASK = (
    "{type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]}"
)
MAX_TASKS = 12  # at most this many tasks a drawn program can ask for (keeps a run short)


@dataclass
class _Drawing:
    """What a program being drawn has so far."""

    draw: st.DrawFn
    semicolons: bool  # whether every statement ends with `;`
    tasks: int = 0  # an upper bound of the tasks the program asks for
    loops: int = 0  # loop counters made (each loop has its own)
    helpers: list[int] = field(default_factory=list)  # the helpers' tasks, by number

    def end(self) -> str:
        return ";" if self.semicolons or self.draw(st.booleans()) else ""

    def budget(self, tasks: int, times: int = 1) -> bool:
        """Take ``tasks`` (asked ``times`` times) from the budget, if it has that much."""
        if self.tasks + tasks * times > MAX_TASKS:
            return False
        self.tasks += tasks * times
        return True


def _statements(d: _Drawing, depth: int, times: int, callable_helpers: int) -> list[str]:
    """Lines of a statement list: each statement runs ``times`` times at most; the helpers
    numbered below ``callable_helpers`` may be called."""
    lines: list[str] = []
    for _ in range(d.draw(st.integers(0, 3 if depth else 5))):
        lines.extend(_statement(d, depth, times, callable_helpers))
    return lines


def _statement(d: _Drawing, depth: int, times: int, callable_helpers: int) -> list[str]:
    kinds = ["wait", "log", "store", "count"]
    if d.tasks + times <= MAX_TASKS:
        kinds += ["wait", "callback", "batch", "if_reading"]
    if callable_helpers:
        kinds += ["call", "call"]
    if depth < 2:
        kinds += ["loop", "random", "try", "try"]
    kind = d.draw(st.sampled_from(kinds))
    if kind in ("wait", "callback", "batch", "if_reading") and not d.budget(
        2 if kind == "batch" else 1, times
    ):
        kind = "count"
    if kind == "wait":
        form = d.draw(st.sampled_from(["bare", "add", "var"]))
        if form == "bare":
            return [f"VV.task.execute({TASK}){d.end()}"]
        if form == "add":
            return [f"n += VV.task.execute({TASK})[0].value{d.end()}"]
        return [f"var got = VV.task.execute({TASK})[0]{d.end()}", f"n += got.value{d.end()}"]
    if kind == "callback":
        return [
            f"VV.task.execute({TASK}, function (data) {{",
            f"  VV.storage.store('seen ' + n, data[0].value){d.end()}",
            "})" + d.end(),
        ]
    if kind == "batch":
        return [
            f"n += VV.task.executeAll([{TASK}, {TASK}], function (data, i) {{",
            f"  VV.log('part ' + i + ': ' + data[0].value){d.end()}",
            "}).length" + d.end(),
        ]
    if kind == "log":
        return [f"VV.log('n is ' + n){d.end()}"]
    if kind == "store":
        key = d.draw(st.sampled_from(["'k' + (n % 3)", "'n' + n", "['a', n].join('-')"]))
        return [f"VV.storage.store({key}, [n, Math.floor(Math.random() * 100)]){d.end()}"]
    if kind == "count":
        return [f"n++{d.end()}"]
    if kind == "call":
        helper = d.draw(st.integers(0, callable_helpers - 1))
        if not d.budget(d.helpers[helper], times):
            return [f"n--{d.end()}"]
        if d.draw(st.booleans()):
            return [f"helper{helper}(n){d.end()}"]  # at a line's start
        return [f"n = helper{helper}(n){d.end()}"]
    if kind == "loop":
        d.loops += 1
        k = f"i{d.loops}"
        count = d.draw(st.integers(0, 2))
        body = _statements(d, depth + 1, times * max(count, 1), callable_helpers)
        return [f"for (var {k} = 0; {k} < {count}; {k}++) {{", *("  " + b for b in body), "}"]
    if kind in ("random", "if_reading"):
        test = (
            "Math.random() < 0.5"
            if kind == "random"
            else f"VV.task.execute({TASK})[0].value % 2 === 0"
        )
        yes = _statements(d, depth + 1, times, callable_helpers)
        no = _statements(d, depth + 1, times, callable_helpers)
        return [
            f"if ({test}) {{",
            *("  " + b for b in yes),
            "} else {",
            *("  " + b for b in no),
            "}",
        ]
    # try / catch / finally around what may wait, or throw
    body = _statements(d, depth + 1, times, callable_helpers)
    if d.draw(st.booleans()):
        body.append(f"throw new Error('boom ' + n){d.end()}")
    catch = d.draw(st.sampled_from(["name", "pattern", "none", "absent"]))
    lines = ["try {", *("  " + b for b in body)]
    if catch == "name":
        lines += ["} catch (e) {", f"  VV.log('caught ' + e.name + ': ' + e.message){d.end()}"]
    elif catch == "pattern":
        lines += [
            "} catch ({name, // what it is",
            "          message = 'none'}) {",
            f"  VV.log('caught ' + name + ': ' + message){d.end()}",
        ]
    elif catch == "none":
        lines += ["} catch {", f"  VV.log('caught'){d.end()}"]
    if catch == "absent" or d.draw(st.booleans()):
        finally_body = _statements(d, depth + 1, times, callable_helpers)
        lines += ["} finally {", f"  VV.log('finally ' + n){d.end()}"]
        lines += ["  " + b for b in finally_body]
    return [*lines, "}"]


@st.composite
def programs(draw: st.DrawFn) -> str:
    d = _Drawing(draw, semicolons=draw(st.booleans()))
    lines: list[str] = []
    for number in range(draw(st.integers(0, 2))):
        # A helper may call the helpers declared before it (never itself: no recursion).
        before = d.tasks
        body = _statements(d, 1, 1, number)
        d.helpers.append(d.tasks - before)
        d.tasks = before  # counted where it is called
        lines += [f"function helper{number}(x) {{", *("  " + b for b in body)]
        lines += [f"  return x + 1{d.end()}", "}"]
    lines.append(f"var n = 0{d.end()}")
    lines += _statements(d, 0, 1, len(d.helpers))
    lines.append(f"VV.storage.store('end', n){d.end()}")
    return "\n".join(lines) + "\n"


def _rejecting(every: int) -> Answer:
    def answer(pending: PendingRequest, time_ms: int) -> dict[str, object]:
        if pending.q % every == every - 1:
            return answer_reject(pending, time_ms=time_ms, message=f"refused {pending.q}")
        return answer_with_readings(pending, time_ms)

    return answer


@settings(
    max_examples=60,
    deadline=None,
    derandomize=True,  # the same programs on every run: CI is reproducible
    database=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
@given(source=programs(), reject_every=st.sampled_from([0, 0, 3]))
def test_resumed_replayed_and_as_written_end_the_same(source: str, reject_every: int) -> None:
    answer = _rejecting(reject_every) if reject_every else answer_with_readings
    plain = drive(source, "plain", answer=answer).ending
    for way in ("warm", "replay", "between"):
        ending = drive(source, way, answer=answer).ending
        assert ending == plain, f"{way} differs from the program as written:\n{source}"
