"""Running one step of a virtual vehicle in V8 (mini-racer), by deterministic replay.

A step runs the program from its first line in a fresh V8 isolate, answers each VVM-API
call from the journal and stops at the first call without an answer (DESIGN.md section 2).
The isolate is created inside the calling process when a step runs, never at import time: an
isolate made before ``fork()`` hangs in the child.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

from py_mini_racer import (
    JSEvalException,
    JSOOMException,
    JSParseException,
    JSTimeoutException,
    MiniRacer,
)

from vvm_worker.runtime.instrument import ReservedNameError, instrument
from vvm_worker.runtime.types import (
    Effect,
    ErrorKind,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    TaskRequest,
    VVError,
)

PROGRAM_NAME = "vv.js"
_PRELUDE_SOURCE = (Path(__file__).with_name("prelude.js")).read_text(encoding="utf-8")
# mini-racer installs these in every context; a VV must not have timers or a console.
_STRIP_GLOBALS = (
    "setTimeout = undefined; clearTimeout = undefined; __timer_manager = undefined;"
    " delete globalThis.console; delete globalThis.WebAssembly;"
)
_OUTCOME_TIMEOUT_S = 1.0
# Fixed cost of re-running a program up to its last answer, on top of the previous step's time.
_REPLAY_SLACK_S = 0.25

_init_lock = threading.Lock()
_initialised = False


def _new_isolate() -> MiniRacer:
    global _initialised
    with _init_lock:
        if not _initialised:
            # V8 reads the time zone once; a VV must not observe the host's (Date is UTC here).
            if os.environ.get("TZ") != "UTC":
                os.environ["TZ"] = "UTC"
                time.tzset()
            _initialised = True
    return MiniRacer()


@dataclass(frozen=True, slots=True)
class SyntaxProblem:
    """A program V8 cannot parse: the message and where (1-based line and column)."""

    message: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"line {self.line}, column {self.column}: {self.message}"


_LOCATION = re.compile(r"^(?P<res>[^\n]*?):(?P<line>\d+): (?P<msg>[^\n]*)")
_FRAME = re.compile(re.escape(PROGRAM_NAME) + r":(\d+):(\d+)")
_USE_STRICT = re.compile(r"""^(?:\s|//[^\n]*\n|/\*.*?\*/)*(['"])use strict\1""", re.S)


def _parse_v8_message(
    text: str, *, parse_error: bool = False
) -> tuple[str, int | None, int | None]:
    """Split a mini-racer exception text into the message and the user's line and column.

    The text is ``RESOURCE:LINE: MESSAGE`` then the source line, a caret under the column and,
    for Error objects, the stack. The place in the program is the thrown-at location when it is
    in the program, otherwise the first stack frame in the program (an API call that threw).
    """
    match = _LOCATION.match(text)
    if match is None:
        return text.strip(), None, None
    message = match.group("msg")
    # A script that does not parse has no name yet: its location is the program's.
    if parse_error or match.group("res").endswith(PROGRAM_NAME):
        lines = text.split("\n")
        column = lines[2].index("^") + 1 if len(lines) > 2 and "^" in lines[2] else None
        return message, int(match.group("line")), column
    frame = _FRAME.search(text)
    if frame is None:
        return message, None, None
    return message, int(frame.group(1)), int(frame.group(2))


@lru_cache(maxsize=512)
def check_syntax(source: str) -> SyntaxProblem | None:
    """V8's verdict on the program's syntax, without running any of it.

    The check evaluates ``throw 0;`` in front of the program on its first line: V8 parses the
    whole script before running it, so a syntax error is reported, and otherwise the throw
    stops it before the first statement. A leading "use strict" directive is kept in front.
    """
    prefix = "throw 0;"
    strict = _USE_STRICT.match(source)
    body = source
    if strict is not None:
        prefix = "'use strict';throw 0;"
        body = (
            source[: strict.start(1)]
            + " " * (strict.end() - strict.start(1))
            + source[strict.end() :]
        )
    mr = _new_isolate()
    try:
        mr.eval(prefix + body + "\n//# sourceURL=" + PROGRAM_NAME, timeout_sec=5.0)
    except JSParseException as exc:
        message, line, column = _parse_v8_message(str(exc), parse_error=True)
        line = line or 1
        column = column or 1
        if line == 1:
            column = max(1, column - len(prefix))
        lines = source.split("\n")
        if line > len(lines):  # "Unexpected end of input" points past the program's end
            line, column = len(lines), len(lines[-1]) + 1
        return SyntaxProblem(message, line, column)
    except JSEvalException:
        return None
    finally:
        mr.close()
    return None


def _prelude_call(step: StepInput) -> str:
    limits = step.limits
    data = {
        "vvId": step.vv_id,
        "vvName": step.vv_name,
        "seed": step.seed,
        "startMs": step.start_ms,
        "catalog": list(step.catalog),
        "journal": list(step.journal),
        "effectsApplied": step.effects_applied,
        "limits": {
            "maxTasks": limits.max_tasks,
            "storageBytes": limits.storage_bytes,
            "allowedCalls": sorted(limits.allowed_calls)
            if limits.allowed_calls is not None
            else None,
        },
    }
    # JSON.parse of a string literal is faster in V8 than the same data as an object literal.
    literal = json.dumps(json.dumps(data, separators=(",", ":")))
    return f"{_PRELUDE_SOURCE}(JSON.parse({literal}));\n//# sourceURL=cpcc-prelude.js"


def _pending(data: Mapping[str, Any]) -> PendingRequest:
    tasks = tuple(TaskRequest.from_json(t) for t in data["tasks"])
    open_ = tuple(int(i) for i in data.get("open", range(len(tasks))))
    return PendingRequest(
        kind=str(data["kind"]),
        q=int(data["q"]),
        fingerprint=data.get("r"),
        tasks=tasks,
        open=open_,
    )


def _effects(items: Sequence[Mapping[str, Any]]) -> tuple[Effect, ...]:
    return tuple(
        Effect(
            seq=int(e["seq"]),
            op=str(e["op"]),
            time_ms=int(e["t"]),
            key=e.get("key"),
            value_json=e.get("value"),
            message=e.get("message"),
        )
        for e in items
    )


def _killed(message: str, quota: str, duration: float) -> StepResult:
    return StepResult(
        Outcome.KILLED,
        error=VVError(ErrorKind.QUOTA, message, quota=quota),
        duration_s=duration,
    )


def run_step(step: StepInput) -> StepResult:
    """Run the VV from its start to its next blocking call, its end, or an error.

    Returns the outcome, the pending request when suspended, the effects not yet applied
    (those numbered ``effects_applied`` and up) and, for a failed or killed VV, an error with
    the line in the program. Never raises for anything the program does.
    """
    problem = check_syntax(step.source)
    if problem is not None:
        return StepResult(
            Outcome.FAILED,
            error=VVError(ErrorKind.SYNTAX, problem.message, problem.line, problem.column),
        )
    try:
        program = instrument(step.source)
    except ReservedNameError as exc:
        return StepResult(
            Outcome.FAILED, error=VVError(ErrorKind.SYNTAX, str(exc), exc.line, exc.column)
        )

    limits = step.limits
    timeout = limits.cpu_s + (2.0 * step.previous_step_s + _REPLAY_SLACK_S if step.journal else 0.0)
    mr = _new_isolate()
    try:
        mr.eval(_STRIP_GLOBALS)
        mr.eval(_prelude_call(step))
        mr.set_hard_memory_limit(limits.heap_bytes)
        thrown: str | None = None
        started = time.perf_counter()
        try:
            mr.eval(program + "\n//# sourceURL=" + PROGRAM_NAME, timeout_sec=timeout)
        except JSTimeoutException:
            # The terminated evaluation still reports back to mini-racer's event loop; let it
            # arrive before the isolate is closed.
            with contextlib.suppress(JSEvalException):
                mr.eval("0", timeout_sec=_OUTCOME_TIMEOUT_S)
            return _killed(
                f"the VV used more than {limits.cpu_s:g} s of CPU time in one step (quota: CPU time per step)",
                "cpu",
                time.perf_counter() - started,
            )
        except JSOOMException:
            return _killed(
                f"the VV used more than {limits.heap_bytes // (1024 * 1024)} MB of heap (quota: V8 heap)",
                "heap",
                time.perf_counter() - started,
            )
        except JSEvalException as exc:
            if mr.was_hard_memory_limit_reached():
                return _killed(
                    f"the VV used more than {limits.heap_bytes // (1024 * 1024)} MB of heap (quota: V8 heap)",
                    "heap",
                    time.perf_counter() - started,
                )
            thrown = str(exc)
        duration = time.perf_counter() - started
        try:
            raw = mr.eval("__cpcc_outcome()", timeout_sec=_OUTCOME_TIMEOUT_S)
            state = json.loads(raw) if isinstance(raw, str) else None
        except (JSEvalException, ValueError):
            state = None
    finally:
        mr.close()
    return _interpret(state, thrown, duration)


def _interpret(state: Any, thrown: str | None, duration: float) -> StepResult:
    if not isinstance(state, dict) or "status" not in state:
        return StepResult(
            Outcome.FAILED,
            error=VVError(
                ErrorKind.PLATFORM, "the program broke the VVM-API (its state could not be read)"
            ),
            duration_s=duration,
        )
    effects = _effects(state.get("effects") or ())
    common: dict[str, Any] = {
        "effects": effects,
        "effects_total": int(state.get("effectsTotal", 0)),
        "duration_s": duration,
        "requests": int(state.get("requests", 0)),
        "storage_bytes": int(state.get("storageBytes", 0)),
    }
    status = state["status"]
    fatal = state.get("fatal")
    if status in ("killed", "failed") and isinstance(fatal, dict):
        kind = ErrorKind.QUOTA if status == "killed" else ErrorKind.NONDETERMINISM
        message = str(fatal.get("message"))
        line = column = None
        if thrown is not None:
            _, line, column = _parse_v8_message(thrown)
        error = VVError(kind, message, line, column, quota=fatal.get("quota"))
        return StepResult(Outcome(status), error=error, **common)
    if status == "suspended":
        return StepResult(Outcome.SUSPENDED, pending=_pending(state["pending"]), **common)
    if thrown is not None:
        message, line, column = _parse_v8_message(thrown)
        if message.startswith("Uncaught "):
            message = message[len("Uncaught ") :]
        return StepResult(
            Outcome.FAILED, error=VVError(ErrorKind.RUNTIME, message, line, column), **common
        )
    if state.get("consumed") != state.get("journalLength"):
        error = VVError(
            ErrorKind.NONDETERMINISM,
            f"non-determinism: on replay the program ended after {state.get('consumed')} of the "
            f"{state.get('journalLength')} answers in its journal; a VV must decide only from what "
            "the VVM-API gave it",
        )
        return StepResult(Outcome.FAILED, error=error, **common)
    return StepResult(Outcome.FINISHED, **common)


# --- journal entries (the host writes these when it answers a pending request) -------------


def answer_task(pending: PendingRequest, *, time_ms: int, data: list[Any]) -> dict[str, Any]:
    """The journal entry answering a pending ``execute`` with its readings."""
    return _entry(pending, "done", time_ms, data=data)


def answer_reject(pending: PendingRequest, *, time_ms: int, message: str) -> dict[str, Any]:
    """The journal entry rejecting a pending ``execute`` or a whole ``executeAll`` batch."""
    return _entry(pending, "reject", time_ms, message=message)


def answer_part(
    pending: PendingRequest, *, index: int, time_ms: int, data: list[Any]
) -> dict[str, Any]:
    """The journal entry answering one task of a pending ``executeAll`` batch."""
    return _entry(pending, "part", time_ms, i=index, data=data)


def _entry(pending: PendingRequest, kind: str, time_ms: int, **fields: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"q": pending.q, "k": kind, "t": int(time_ms), **fields}
    if pending.fingerprint is not None:
        entry["r"] = pending.fingerprint
    return entry
