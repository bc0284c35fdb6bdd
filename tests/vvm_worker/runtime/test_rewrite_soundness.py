"""The rewrite of a program (instrument.py) changes nothing the program can observe.

Each program here runs five ways and must end the same (outcome, error with its place,
storage, log, the requests it made): resumed in one warm context (``warm``), replayed in a new
context at every step (``replay``), warm but moved to another host now and then (``mixed``:
it replays once there, then resumes), moved back and forth between two hosts that keep its
context (``between``: back on a host, it catches up on the steps made on the other), and not
made suspendable at all (``plain``: compiled as the plain function it was written as, only its
catch and finally clauses instrumented, and replayed at every step).
"""

from __future__ import annotations

import contextlib
import importlib
import json
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any

import pytest

from tests.vvm_worker.runtime.harness import (
    CATALOG,
    START_MS,
    Answer,
    answer_with_readings,
    reject_all,
)
from vvm_worker.runtime import (
    ErrorKind,
    Outcome,
    PendingRequest,
    Runtime,
    StepInput,
    VVContext,
    check_syntax,
    run_step,
)
from vvm_worker.runtime.instrument import Instrumented, ReservedNameError, instrument_program

TASK = (
    "{type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]}"
)
WAYS = ("warm", "replay", "mixed", "between", "plain")


@dataclass(frozen=True)
class Ending:
    """How a program ended, as the platform saw it."""

    outcome: Outcome
    error: tuple[ErrorKind, str, int | None, int | None] | None
    storage: dict[str, Any]
    log: list[str]
    requests: list[PendingRequest]


@dataclass(frozen=True)
class Driven:
    ending: Ending
    answers_read: list[int]  # per step
    generator: bool  # whether the platform made the program suspendable


def _plain(source: str, *, suspendable: bool = True) -> Instrumented:
    return instrument_program(source, suspendable=False)


@contextlib.contextmanager
def not_rewritten() -> Iterator[None]:
    """Steps in this block compile programs as written (only catch and finally are
    instrumented): every step replays."""
    module = importlib.import_module(VVContext.__module__)  # where contexts are made
    saved = module.instrument_program
    module.instrument_program = _plain
    try:
        yield
    finally:
        module.instrument_program = saved


def _suspendable(source: str) -> bool:
    if check_syntax(source) is not None:
        return False
    try:
        return instrument_program(source).generator
    except ReservedNameError:
        return False


def drive(
    source: str,
    way: str,
    *,
    answer: Answer = answer_with_readings,
    seed: int = 5,
    move_every: int = 3,
    max_steps: int = 300,
) -> Driven:
    """Step the VV to its end the given way (see the module docstring), answering each
    request with ``answer``, applying effects as the VVM does."""
    runtime = Runtime() if way in ("warm", "mixed", "between") else None
    hosts = [runtime, Runtime()] if way == "between" else []
    journal: list[dict[str, Any]] = []
    applied = 0
    storage: dict[str, Any] = {}
    log: list[str] = []
    requests: list[PendingRequest] = []
    reads: list[int] = []
    context = not_rewritten() if way == "plain" else contextlib.nullcontext()
    try:
        with context:
            for n in range(max_steps):
                if way == "mixed" and n and n % move_every == 0:
                    assert runtime is not None
                    runtime.close()
                    runtime = Runtime()  # moved to another host
                if way == "between":
                    runtime = hosts[(n // move_every) % 2]
                step = StepInput(
                    vv_id="vv-s",
                    vv_name="vv-s",
                    source=source,
                    seed=seed,
                    start_ms=START_MS,
                    catalog=CATALOG,
                    journal=list(journal),
                    effects_applied=applied,
                )
                result = runtime.step(step) if runtime is not None else run_step(step)
                reads.append(result.answers_read)
                for e in result.effects:
                    assert e.seq >= applied, "an effect was reported twice"
                    if e.op == "store":
                        assert e.key is not None and e.value_json is not None
                        storage[e.key] = json.loads(e.value_json)
                    elif e.op == "remove":
                        assert e.key is not None
                        storage.pop(e.key, None)
                    else:
                        assert e.message is not None
                        log.append(e.message)
                applied = max(applied, result.effects_total)
                if result.outcome is not Outcome.SUSPENDED:
                    error = result.error
                    ending = Ending(
                        result.outcome,
                        None
                        if error is None
                        else (error.kind, error.message, error.line, error.column),
                        storage,
                        log,
                        requests,
                    )
                    return Driven(ending, reads, way != "plain" and _suspendable(source))
                assert result.pending is not None
                requests.append(result.pending)
                journal.append(answer(result.pending, START_MS + 1000 * (n + 1)))
    finally:
        for each in {id(r): r for r in [runtime, *hosts] if r is not None}.values():
            each.close()
    raise AssertionError("the program did not end")


def every_way(source: str, *, answer: Answer = answer_with_readings) -> dict[str, Driven]:
    """The program driven each way; asserts that all end the same and that a suspendable
    program resumed in its warm context."""
    driven = {way: drive(source, way, answer=answer) for way in WAYS}
    plain = driven["plain"].ending
    for way in ("warm", "replay", "mixed", "between"):
        assert driven[way].ending == plain, f"{way} differs from the program as written"
    warm = driven["warm"]
    if warm.generator and len(warm.answers_read) > 2:
        assert warm.answers_read[2:] == [1] * (len(warm.answers_read) - 2), warm.answers_read
    return driven


def finished(source: str, *, answer: Answer = answer_with_readings) -> Ending:
    driven = every_way(source, answer=answer)
    ending = driven["warm"].ending
    assert ending.outcome is Outcome.FINISHED, ending.error
    return ending


# --- 1. programs without semicolons -----------------------------------------------------------

NO_SEMICOLONS = [
    # A line ending in a value: the inserted `(` would call it with the readings.
    f"var count = 0\nVV.task.execute({TASK})\ncount++\nVV.storage.store('count', count)",
    f"var top = Math.max(1, 2)\nVV.task.execute({TASK}).length\nVV.storage.store('top', top)",
    # A line ending in a function expression: it would be called with the readings.
    "var called = false\nvar f = function () { called = true }\n"
    f"VV.task.execute({TASK})\nVV.storage.store('called', called)",
    # A directive: `'use strict'(...)` would be a call, and no directive.
    f"'use strict'\nVV.task.execute({TASK})\n"
    "VV.storage.store('strict', (function () { return this === undefined })())",
    # A helper's call, and the waiting call in the helper, at the start of a line.
    f"function visit(k) {{\n  var d = k\n  VV.task.execute({TASK})\n  return d\n}}\n"
    "var n = 1\nvisit(n)\nvar m = 2\nvisit(m)\nVV.storage.store('n', [n, m])",
    # In a block, after a comment, and in switch cases.
    f"var k = 1\n{{\n  k = 2\n  // waiting\n  VV.task.execute({TASK})\n}}\nVV.storage.store('k', k)",
    f"switch (2) {{\n  case 2: var a = 1\n  VV.task.execute({TASK})\n"
    f"  default: a++\n  VV.task.execute({TASK})\n}}\nVV.storage.store('a', a)",
    # A statement standing alone: after `)`, `else`, `do` or `:` a `(` cannot join.
    f"var n = 0\nif (n === 0) VV.task.execute({TASK})\nelse VV.task.execute({TASK})\n"
    f"if (n === 1) n = 5\nelse VV.task.execute({TASK})\n"
    f"for (var i = 0; i < 2; i++) VV.task.execute({TASK})\n"
    f"while (n++ < 2) VV.task.execute({TASK})\n"
    f"do VV.task.execute({TASK})\nwhile (n++ < 4)\n"
    f"here: VV.task.execute({TASK})\nVV.storage.store('n', n)",
]


@pytest.mark.parametrize("source", NO_SEMICOLONS)
def test_a_program_without_semicolons_waits_where_it_is_written(source: str) -> None:
    assert check_syntax(source) is None
    assert instrument_program(source).generator
    ending = finished(source)
    assert ending.storage


def test_an_error_after_an_inserted_semicolon_has_the_users_column() -> None:
    source = f"var n = 0\nVV.task.execute({TASK}, function () {{ null.x }})\n"
    assert ";(yield*" in instrument_program(source).code
    driven = every_way(source)
    error = driven["warm"].ending.error
    assert error is not None and error[1].startswith("TypeError: Cannot read properties of null")
    assert error[2:] == (2, source.split("\n")[1].index("null.x") + 6)


def test_a_call_ending_where_a_finally_block_ends_resumes() -> None:
    source = f"for (var k = 0; k < 3; k++) try {{ k += 0 }} finally {{VV.task.execute({TASK})}}"
    ending = finished(source)
    assert len(ending.requests) == 3
    assert every_way(source)["warm"].generator


# --- 2. catch clauses with a destructuring pattern ----------------------------------------------


def test_a_comment_in_a_catch_pattern_is_left_where_it_is() -> None:
    source = (
        f"VV.task.execute({TASK})\n"
        "try { throw {message: 'm', code: 4} } catch ({message, // the text\n"
        "  code /* the number */}) {\n"
        "  VV.storage.store('caught', [message, code])\n"
        "}\n"
    )
    assert finished(source).storage == {"caught": ["m", 4]}


def test_a_catch_patterns_default_values_keep_their_text_and_scope() -> None:
    source = (
        "var seen = 'outer';\n"
        f"VV.task.execute({TASK});\n"
        "try { throw {}; } catch ({text = 'two  spaces,\\ta tab',\n"
        "                         which = typeof seen, late = typeof later}) {\n"
        "  let seen = 'inner', later = 1;\n"
        "  VV.storage.store('caught', [text, which, late]);\n"
        "}\n"
    )
    # The defaults are evaluated where the pattern is, before the block's own `let`s.
    ending = finished(source)
    assert ending.storage == {"caught": ["two  spaces,\ta tab", "string", "undefined"]}


def test_a_catch_pattern_does_not_catch_the_suspension() -> None:
    source = (
        "var tries = 0, caught = [];\n"
        "for (var k = 0; k < 3; k++) {\n"
        f"  try {{ tries++; VV.task.execute({TASK}); }} catch ({{name, message}}) {{\n"
        "    caught.push(name + ': ' + message);\n"
        "  } finally { VV.log('try ' + k); }\n"
        "}\n"
        "VV.storage.store('result', [tries, caught]);\n"
    )
    assert finished(source).storage == {"result": [3, []]}
    ending = finished(source, answer=reject_all("no vehicle"))
    assert ending.storage == {
        "result": [3, ["TaskRejectedError: no vehicle"] * 3],
    }
    assert ending.log == ["try 0", "try 1", "try 2"]


def test_errors_on_the_line_of_a_catch_pattern_have_the_users_columns() -> None:
    line = "try { throw {}; } catch ({a = null.x}) { VV.log(a); }"
    source = f"VV.task.execute({TASK});\n{line}\n"
    error = every_way(source)["warm"].ending.error
    assert error is not None and "Cannot read properties of null" in error[1]
    assert error[2:] == (2, line.index("null.x") + 6)
    line = "try { throw {}; } catch ({a}) { VV.log(a); null.y; }"
    source = f"VV.task.execute({TASK});\n{line}\n"
    error = every_way(source)["warm"].ending.error
    assert error is not None and "Cannot read properties of null" in error[1]
    assert error[2:] == (2, line.index("null.y") + 6)


# --- 3. unicode escapes in identifiers -----------------------------------------------------------


def test_a_vv_of_the_programs_own_named_with_an_escape_is_the_programs() -> None:
    source = (
        "var V\\u0056 = {\n"
        "  task: {execute: function () { return ['mine']; }},\n"
        "  storage: globalThis.VV.storage,\n"
        "};\n"
        "VV.storage.store('got', VV.task.execute('a task'));\n"
    )
    assert finished(source).storage == {"got": ["mine"]}


def test_an_escaped_name_of_the_platforms_vv_waits_as_vv() -> None:
    source = (
        f"for (var k = 0; k < 3; k++) V\\u0056.task.ex\\u0065cute({TASK});\n"
        "VV.storage.store('k', k);\n"
    )
    assert instrument_program(source).generator
    assert finished(source).storage == {"k": 3}


def test_a_helper_named_with_an_escape_is_the_helper() -> None:
    source = (
        f"function visit() {{ return VV.task.execute({TASK}); }}\n"
        "var again = vis\\u0069t;\n"
        "VV.storage.store('got', [Array.isArray(again()), Array.isArray(v\\u{69}sit())]);\n"
    )
    assert finished(source).storage == {"got": [True, True]}


def test_an_escaped_yield_keeps_the_program_as_written() -> None:
    source = f"var yi\\u0065ld = 2;\nVV.task.execute({TASK});\nVV.storage.store('y', yield);\n"
    assert not instrument_program(source).generator
    assert finished(source).storage == {"y": 2}


def test_an_escaped_reserved_name_is_refused_with_its_place() -> None:
    source = f"VV.task.execute({TASK});\nvar ok = 1, \\u005f_cpcc_rethrow = 2;\n"
    for way in WAYS:
        ending = drive(source, way).ending
        assert ending.outcome is Outcome.FAILED
        assert ending.error is not None
        kind, message, line, column = ending.error
        assert kind is ErrorKind.SYNTAX
        assert "'__cpcc_rethrow' is reserved" in message
        assert (line, column) == (2, 13)


# --- 4. recursion through helpers ---------------------------------------------------------------

DEPTH = 5000  # the program as written reaches it; as a generator, V8's stack ends near 3,700

RECURSIVE = [
    f"""
function down(k) {{
  if (k === 0) return VV.task.execute({TASK})[0].value;
  return down(k - 1) + 1;
}}
VV.storage.store('r', down({DEPTH}));
VV.storage.store('again', down(3));
""",
    f"""
function even(k) {{ return k === 0 ? VV.task.execute({TASK})[0].value : odd(k - 1) + 1; }}
function odd(k) {{ return k === 0 ? VV.task.execute({TASK})[0].value : even(k - 1) + 1; }}
function start(k) {{ return even(k); }}
VV.storage.store('r', start({DEPTH}));
VV.storage.store('again', start(3));
""",
]


@pytest.mark.parametrize("source", RECURSIVE)
def test_a_recursive_helper_that_waits_reaches_the_depth_of_the_program_as_written(
    source: str,
) -> None:
    assert finished(source).storage == {"r": DEPTH, "again": 4}


# --- 5. async functions ---------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("source", "message", "line", "column"),
    [
        (
            f"var n = 0;\nasync function f() {{\n  await 1;\n  VV.storage.store('n', 1);\n}}\n"
            f"f();\nVV.task.execute({TASK});\n",
            "async functions are not supported: VV.task.execute blocks until its task is done,"
            " so a VV program needs no async or await",
            2,
            1,
        ),
        (
            f"VV.task.execute({TASK});\n[1].forEach(async (x) => {{ await x; }});\n",
            "async arrow functions are not supported",
            2,
            13,
        ),
        (
            "var o = {\n  go: function () {},\n  async later() {},\n};\n",
            "async methods are not supported",
            3,
            3,
        ),
        ("var m = import('fs');\n", "import() is not supported", 1, 9),
    ],
)
def test_async_and_import_are_refused_with_their_place(
    source: str, message: str, line: int, column: int
) -> None:
    problem = check_syntax(source)
    assert problem is not None
    assert problem.message.startswith(message)
    assert (problem.line, problem.column) == (line, column)
    for way in WAYS:
        ending = drive(source, way).ending
        assert ending.outcome is Outcome.FAILED
        assert ending.error is not None
        assert ending.error[0] is ErrorKind.SYNTAX
        assert ending.error[1].startswith(message)
        assert ending.error[2:] == (line, column)
        assert ending.storage == {}
