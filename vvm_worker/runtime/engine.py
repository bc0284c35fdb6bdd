"""Running the steps of virtual vehicles in V8 (mini-racer): resumed where they wait, or
replayed.

A step runs the program from its first line, answers each VVM-API call from the journal and
stops at the first call without an answer (DESIGN.md section 2). A ``VVContext`` is one VV's
V8 isolate with the prelude, the SDC entries, the compiled program and the journal entries it
has seen; ``Runtime`` keeps one warm context per VV while the VV stays on this host and sends
each step only the journal entries the context does not have yet, in the same call into the
isolate as the step (which returns the outcome too). ``run_step`` runs one step in a context
made for it.

In a warm context the program does not re-run: where it can, the platform compiles it as a
generator whose waiting calls yield (instrument.py), so between steps it stays suspended at its
pending call and the next step resumes it there, reading only the new answer; a step then
costs the same at a VV's 5,000th task as at its 5th. Replay from the journal remains how a
program resumes in a new context (after a move or a crash) and whenever resuming would not be
exact (see prelude.js); ``StepResult.answers_read`` says which a step did. A program that waits
somewhere the platform cannot turn into a ``yield`` (in a callback, in a function it uses as a
value) is replayed at each step, as before.

Suspending a blocking program without the rewrite is not possible with mini-racer: the only
way a synchronous program can wait for the host is a loop around ``Atomics.wait`` with a
timeout, polling a SharedArrayBuffer (the host cannot wake it). Measured for issue 13, that
costs each idle VV about 1 % of a core at a 1 ms poll and 0.3 % at 5 ms, and while the program
waits, the isolate answers nothing else (not even its heap size).

Isolates are created inside the calling process when a step runs, never at import time: an
isolate made before ``fork()`` hangs in the child.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import os
import secrets
import time
from collections import OrderedDict
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from vvm_worker.runtime import v8
from vvm_worker.runtime.instrument import Instrumented, ReservedNameError, instrument_program
from vvm_worker.runtime.syntax import PROGRAM_NAME, check_syntax, parse_v8_message
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
from vvm_worker.runtime.v8 import (
    JSEvalException,
    JSOOMException,
    JSParseException,
    JSTimeoutException,
)

logger = logging.getLogger(__name__)

_PRELUDE_SOURCE = (Path(__file__).with_name("prelude.js")).read_text(encoding="utf-8")
_HOST_TIMEOUT_S = 5.0
# New journal entries up to this much JSON text go to the isolate with the step itself (one
# call instead of two); more, as when a VV arrives with its journal, in a call of their own,
# so that reading them does not count against the step's CPU time.
_APPEND_WITH_STEP_CHARS = 64 * 1024
# Fixed cost of re-running a program up to its last answer, on top of the previous step's time.
_REPLAY_SLACK_S = 0.25

_WARM_UP_CATALOG = json.dumps(
    json.dumps([{"name": "GPS", "kind": "gps", "unit": "", "params": {}}])
)
_WARM_UP_PROGRAM = (
    "var g = VV.sensor.get('GPS'); VV.storage.store('k', 1); VV.storage.load('k'); VV.log('x');"
    " VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), sensors: [g]});"
)
_WARM_UP_RUN = json.dumps(
    json.dumps(
        {
            "vvId": "",
            "vvName": "",
            "seed": 1,
            "startMs": 0,
            "effectsApplied": 0,
            "limits": {"maxTasks": 10, "storageBytes": 1000, "allowedCalls": None},
        }
    )
)


@dataclass
class _Prepared:
    """An isolate with the prelude installed (built-ins frozen), not yet given to a VV."""

    isolate: v8.Isolate
    key: str  # the host key, as a JSON string literal


async def _prepare() -> _Prepared:
    """A new isolate with the prelude; on the V8 thread."""
    isolate = v8.adopt()
    key = json.dumps(secrets.token_hex(16))

    async def run(code: str) -> Any:
        return await isolate.eval_async(code, timeout_s=_HOST_TIMEOUT_S)

    try:
        await run(f"{_PRELUDE_SOURCE}({key});\n//# sourceURL=cpcc-prelude.js")
        # One throw-away run compiles the prelude's functions now rather than in a VV's step.
        await run(f"__cpcc_host.setCatalog({key}, {_WARM_UP_CATALOG})")
        await run(f"__cpcc_host.setProgram({key}, function () {{ {_WARM_UP_PROGRAM} }})")
        with contextlib.suppress(JSEvalException):
            await run(f"__cpcc_host.step({key}, {_WARM_UP_RUN})")
        await run(f"__cpcc_host.outcome({key})")
    except BaseException:
        isolate.close()
        raise
    return _Prepared(isolate, key)


class IsolatePool:
    """Isolates with the prelude installed, made ahead of time on the V8 thread.

    A new isolate and the prelude's freezing of the built-ins cost about 5 ms; taking a
    prepared one makes a VV's first step on a host cost little more than its program.
    ``size`` 0 prepares every isolate when it is needed. The pool's state lives on the V8
    thread (no lock): ``take`` is a call to it.
    """

    def __init__(self, size: int) -> None:
        self.size = size
        self._loop: asyncio.AbstractEventLoop | None = None
        self._ready: list[_Prepared] = []
        self._filling: asyncio.Task[None] | None = None

    def take(self) -> _Prepared:
        return v8.call(self._take)

    async def _take(self) -> _Prepared:
        loop = asyncio.get_running_loop()
        if self._loop is not loop:  # first use, or a new owner (after a fork)
            self._loop, self._ready, self._filling = loop, [], None
        prepared = self._ready.pop() if self._ready else await _prepare()
        if self._filling is None and len(self._ready) < self.size:
            self._filling = loop.create_task(self._fill())
        return prepared

    async def _fill(self) -> None:
        try:
            while len(self._ready) < self.size:
                self._ready.append(await _prepare())
        except Exception:
            logger.exception("isolates could not be prepared ahead of time")
        finally:
            self._filling = None


POOL = IsolatePool(int(os.environ.get("CPCC_ISOLATE_POOL", "2")))


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


def _entry_text(entry: Mapping[str, Any] | str) -> str:
    """An entry as JSON text: entries may come as objects or, straight from a database, as
    text (which saves decoding and encoding them again)."""
    if isinstance(entry, str):
        return entry
    return json.dumps(entry, sort_keys=True, separators=(",", ":"))


class StaleContext(Exception):
    """The context cannot run the step: its journal is not a prefix of the VV's journal (it
    was rolled back), or a program it kept suspended left what a new run would see."""


class VVContext:
    """One VV's warm V8 isolate: prelude, SDC entries, compiled program and journal so far.

    Raises ReservedNameError when the program uses a name reserved for the platform. The
    program's syntax must have been checked (``check_syntax``).
    """

    def __init__(self, *, vv_id: str, source: str, catalog: Sequence[Mapping[str, Any]]) -> None:
        program = instrument_program(source)
        self.vv_id = vv_id
        self.source = source
        self.usable = True
        self.journal_length = 0
        self._last_entry: str | None = None
        prepared = POOL.take()
        self._isolate = prepared.isolate
        self._key = prepared.key
        try:
            self._host("setCatalog", json.dumps(list(catalog)))
            try:
                self._set_program(program)
            except JSParseException:
                if not program.generator:
                    raise
                # V8 refuses the generator form of a program it parses as written (a case the
                # rewrite did not foresee): run it the replay way.
                self._set_program(instrument_program(source, suspendable=False))
        except BaseException:
            self.close()
            raise

    def _set_program(self, program: Instrumented) -> None:
        function = "function*" if program.generator else "function"
        self._program_prefix = f"__cpcc_host.setProgram({self._key}, {function} () {{"
        self._isolate.eval(
            f"{self._program_prefix}{program.code}\n}});\n//# sourceURL={PROGRAM_NAME}",
            timeout_s=_HOST_TIMEOUT_S,
        )
        self._program = program

    def _host_script(self, call: str, *args: str) -> str:
        arguments = ", ".join([self._key, *(json.dumps(a) for a in args)])
        return f"__cpcc_host.{call}({arguments})"

    def _host(self, call: str, *args: str) -> Any:
        return self._isolate.eval(self._host_script(call, *args), timeout_s=_HOST_TIMEOUT_S)

    async def _host_async(self, call: str, *args: str, timeout: float = _HOST_TIMEOUT_S) -> Any:
        return await self._isolate.eval_async(self._host_script(call, *args), timeout_s=timeout)

    def heap_bytes(self) -> int:
        """Bytes of V8 heap this context uses now."""
        return int(self._isolate.heap_stats()["used_heap_size"])

    def close(self) -> None:
        self.usable = False
        self._isolate.close()

    def _new_entries(self, journal: Sequence[Mapping[str, Any] | str]) -> list[str]:
        """The entries of ``journal`` this context does not have yet, as JSON text."""
        have = self.journal_length
        if len(journal) < have:
            raise StaleContext(self.vv_id)
        # One read for the last entry this context has (still the same?) and the new ones.
        tail = list(journal[have - 1 :]) if have else list(journal[0:])
        if have and _entry_text(tail[0]) != self._last_entry:
            raise StaleContext(self.vv_id)
        return [_entry_text(e) for e in (tail[1:] if have else tail)]

    def _appended(self, texts: list[str]) -> None:
        if texts:
            self.journal_length += len(texts)
            self._last_entry = texts[-1]

    def step(self, step: StepInput) -> StepResult:
        """Run the program once more from its start with the journal of ``step``.

        Never raises for anything the program does; raises StaleContext when the context's
        journal is not a prefix of the step's (the caller makes a new context).
        """
        texts = self._new_entries(step.journal)
        entries = "[" + ",".join(texts) + "]"
        if len(entries) > _APPEND_WITH_STEP_CHARS:
            self._host("append", entries)
            self._appended(texts)
            texts = []
        limits = step.limits
        timeout = limits.cpu_s + (
            2.0 * step.previous_step_s + _REPLAY_SLACK_S if len(step.journal) else 0.0
        )
        run = {
            "vvId": step.vv_id,
            "vvName": step.vv_name,
            "seed": step.seed,
            "startMs": step.start_ms,
            "effectsApplied": step.effects_applied,
            "limits": {
                "maxTasks": limits.max_tasks,
                "storageBytes": limits.storage_bytes,
                "allowedCalls": sorted(limits.allowed_calls)
                if limits.allowed_calls is not None
                else None,
            },
        }
        run_json = json.dumps(run, separators=(",", ":"))
        arguments = (run_json, entries) if texts else (run_json,)
        raw, thrown, killed_by, duration = v8.call(
            lambda: self._run(arguments, heap_bytes=limits.heap_bytes, timeout=timeout)
        )
        self._appended(texts)
        killed: tuple[str, str] | None = None
        if killed_by == "cpu":
            killed = (
                f"the VV used more than {limits.cpu_s:g} s of CPU time in one step "
                "(quota: CPU time per step)",
                "cpu",
            )
        elif killed_by == "heap":
            killed = (self._heap_message(step), "heap")
        if killed is not None:
            # V8 stopped the program where it was; what it did before (a callback's storage
            # writes, say) still counts. The isolate is not used again.
            self.usable = False
        try:
            state = json.loads(raw) if isinstance(raw, str) else None
        except ValueError:
            state = None
        if isinstance(state, dict) and state.get("status") == "stale":
            self.usable = False
            raise StaleContext(self.vv_id)
        # A context whose isolate lacks an entry this side counts would replay wrongly.
        if (
            not isinstance(state, dict)
            or state.get("tainted")
            or state.get("journalLength") != self.journal_length
        ):
            self.usable = False
        if killed is not None:
            effects = _effects(state.get("effects") or ()) if isinstance(state, dict) else ()
            total = int(state.get("effectsTotal", 0)) if isinstance(state, dict) else 0
            message, quota = killed
            return StepResult(
                Outcome.KILLED,
                error=VVError(ErrorKind.QUOTA, message, quota=quota),
                effects=effects,
                effects_total=total,
                duration_s=duration,
            )
        return self._interpret(state, thrown, duration)

    async def _run(
        self, arguments: tuple[str, ...], *, heap_bytes: int, timeout: float
    ) -> tuple[Any, str | None, str | None, float]:
        """The step's work in V8, on the V8 thread: the outcome's text (when there is one), the
        text of what the program threw, what stopped it (``cpu``, ``heap``) and how long it
        ran."""
        isolate = self._isolate
        isolate.set_hard_memory_limit(heap_bytes)
        raw: Any = None  # the outcome, when the step returns it
        thrown: str | None = None
        killed_by: str | None = None
        started = time.perf_counter()
        try:
            raw = await self._host_async("step", *arguments, timeout=timeout)
        except JSTimeoutException:
            killed_by = "cpu"
        except JSOOMException:
            killed_by = "heap"
        except JSEvalException as exc:
            if isolate.hard_memory_limit_reached():
                killed_by = "heap"
            else:
                thrown = str(exc)
        duration = time.perf_counter() - started
        if killed_by is not None:
            isolate.set_hard_memory_limit(0)
            with contextlib.suppress(JSEvalException):
                await self._host_async("abort")
        if not isinstance(raw, str):
            with contextlib.suppress(JSEvalException):
                raw = await self._host_async("outcome")
        return raw, thrown, killed_by, duration

    @staticmethod
    def _heap_message(step: StepInput) -> str:
        mb = step.limits.heap_bytes // (1024 * 1024)
        return f"the VV used more than {mb} MB of heap (quota: V8 heap)"

    def _place(self, thrown: str) -> tuple[str, int | None, int | None]:
        """The message of a V8 exception and its line and column in the user's program."""
        message, line, column = parse_v8_message(
            thrown, first_line_offset=len(self._program_prefix)
        )
        if line is not None and column is not None:
            column = self._program.user_column(line, column)
        return message, line, column

    def _interpret(self, state: Any, thrown: str | None, duration: float) -> StepResult:
        if not isinstance(state, dict) or "status" not in state:
            return StepResult(
                Outcome.FAILED,
                error=VVError(
                    ErrorKind.PLATFORM,
                    "the program broke the VVM-API (its state could not be read)",
                ),
                duration_s=duration,
            )
        common: dict[str, Any] = {
            "effects": _effects(state.get("effects") or ()),
            "effects_total": int(state.get("effectsTotal", 0)),
            "duration_s": duration,
            "requests": int(state.get("requests", 0)),
            "storage_bytes": int(state.get("storageBytes", 0)),
            "answers_read": int(state.get("answersRead", 0)),
        }
        status = state["status"]
        fatal = state.get("fatal")
        if status in ("killed", "failed") and isinstance(fatal, dict):
            kind = ErrorKind.QUOTA if status == "killed" else ErrorKind.NONDETERMINISM
            line = column = None
            if thrown is not None:
                _, line, column = self._place(thrown)
            error = VVError(kind, str(fatal.get("message")), line, column, quota=fatal.get("quota"))
            return StepResult(Outcome(status), error=error, **common)
        if status == "suspended":
            return StepResult(Outcome.SUSPENDED, pending=_pending(state["pending"]), **common)
        if thrown is not None:
            message, line, column = self._place(thrown)
            if message.startswith("Uncaught "):
                message = message[len("Uncaught ") :]
            error = VVError(ErrorKind.RUNTIME, message, line, column)
            return StepResult(Outcome.FAILED, error=error, **common)
        if state.get("consumed") != state.get("journalLength"):
            error = VVError(
                ErrorKind.NONDETERMINISM,
                f"non-determinism: on replay the program ended after {state.get('consumed')} of "
                f"the {state.get('journalLength')} answers in its journal; a VV must decide only "
                "from what the VVM-API gave it",
            )
            return StepResult(Outcome.FAILED, error=error, **common)
        return StepResult(Outcome.FINISHED, **common)


def _syntax_failure(step: StepInput) -> StepResult | None:
    problem = check_syntax(step.source)
    if problem is not None:
        error = VVError(ErrorKind.SYNTAX, problem.message, problem.line, problem.column)
        return StepResult(Outcome.FAILED, error=error)
    return None


class Runtime:
    """The steps of the VVs on this host, each in its warm context while it stays here.

    Keeps at most ``max_contexts`` contexts (the least recently used goes first); a context
    is dropped when its VV ends, is killed, or leaves (``forget``). Not thread-safe: one
    runtime per worker thread.
    """

    def __init__(self, *, max_contexts: int = 64) -> None:
        self.max_contexts = max_contexts
        self._contexts: OrderedDict[str, VVContext] = OrderedDict()

    def __len__(self) -> int:
        return len(self._contexts)

    def context(self, vv_id: str) -> VVContext | None:
        return self._contexts.get(vv_id)

    def step(self, step: StepInput) -> StepResult:
        """Run one step of the VV: from its warm context when it has one, else a new one."""
        failure = _syntax_failure(step)
        if failure is not None:
            self.forget(step.vv_id)
            return failure
        ctx = self._contexts.pop(step.vv_id, None)
        if ctx is not None and (not ctx.usable or ctx.source != step.source):
            ctx.close()
            ctx = None
        result: StepResult | None = None
        if ctx is not None:
            try:
                result = ctx.step(step)
            except StaleContext:
                ctx.close()
                ctx = None
        if ctx is None:
            try:
                ctx = VVContext(vv_id=step.vv_id, source=step.source, catalog=step.catalog)
            except ReservedNameError as exc:
                error = VVError(ErrorKind.SYNTAX, str(exc), exc.line, exc.column)
                return StepResult(Outcome.FAILED, error=error)
            result = ctx.step(step)
        assert result is not None
        if ctx.usable and result.outcome is Outcome.SUSPENDED and self.max_contexts > 0:
            self._contexts[step.vv_id] = ctx
            while len(self._contexts) > self.max_contexts:
                _, oldest = self._contexts.popitem(last=False)
                oldest.close()
        else:
            ctx.close()
        return result

    def forget(self, vv_id: str) -> None:
        """Drop the VV's context (it left this host, or ended)."""
        ctx = self._contexts.pop(vv_id, None)
        if ctx is not None:
            ctx.close()

    def close(self) -> None:
        while self._contexts:
            _, ctx = self._contexts.popitem()
            ctx.close()


def run_step(step: StepInput) -> StepResult:
    """Run one step of the VV in a context made for it (no warm context is kept).

    Returns the outcome, the pending request when suspended, the effects not yet applied
    (those numbered ``effects_applied`` and up) and, for a failed or killed VV, an error with
    the line in the program. Never raises for anything the program does.
    """
    return Runtime(max_contexts=0).step(step)


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
