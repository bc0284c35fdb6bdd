"""One VV's warm V8 isolate: the prelude, its SDC entries, its compiled program and the
journal entries it has seen (``VVContext``).

A step runs in one call into the isolate, from the thread that steps the VV (``v8.direct``):
the new journal entries go with it and the outcome comes back. Where the program was compiled
as a generator (instrument.py) it stays suspended at its waiting call between steps and the
next step resumes it there, reading only the new answer; otherwise, and in a new context, the
step replays the program from its first line, answering each VVM-API call from the journal
(prelude.js says when resuming would not be exact).
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import time
from collections.abc import Mapping, Sequence
from typing import Any

from vvm_worker.runtime import v8
from vvm_worker.runtime.instrument import Instrumented, instrument_program
from vvm_worker.runtime.pool import HOST_TIMEOUT_S, POOL
from vvm_worker.runtime.syntax import PROGRAM_NAME, parse_v8_message
from vvm_worker.runtime.types import (
    Effect,
    ErrorKind,
    Outcome,
    PendingRequest,
    StepInput,
    StepResult,
    VVError,
)
from vvm_worker.runtime.v8 import (
    JSEvalException,
    JSOOMException,
    JSParseException,
    JSTimeoutException,
)

# New journal entries up to this much JSON text go to the isolate with the step itself (one
# call instead of two); more, as when a VV arrives with its journal, in a call of their own,
# so that reading them does not count against the step's CPU time.
_APPEND_WITH_STEP_CHARS = 64 * 1024
# Fixed cost of re-running a program up to its last answer, on top of the time it took.
_REPLAY_SLACK_S = 0.25
# What prelude.js's stepIfResumes gives back when the step would not resume (nothing done).
_REPLAY = "replay"


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
        self._stepped = False
        prepared = POOL.take()
        self._isolate = prepared.isolate
        self._key = prepared.key
        catalog_json = json.dumps(list(catalog))
        try:
            try:
                self._set_program(program, catalog_json)
            except JSParseException:
                if not program.generator:
                    raise
                # V8 refuses the generator form of a program it parses as written (a case the
                # rewrite did not foresee): run it the replay way.
                self._set_program(instrument_program(source, suspendable=False), catalog_json)
        except BaseException:
            self.close()
            raise

    def _set_program(self, program: Instrumented, catalog_json: str) -> None:
        """Give the isolate the program and the VV's catalog, in one call (the catalog after
        the program's last line, so that the program's lines keep their numbers)."""
        function = "function*" if program.generator else "function"
        self._program_prefix = f"__cpcc_host.setProgram({self._key}, {function} () {{"
        catalog = self._host_script("setCatalog", catalog_json)
        self._isolate.eval(
            f"{self._program_prefix}{program.code}\n}}); {catalog};\n//# sourceURL={PROGRAM_NAME}",
            timeout_s=HOST_TIMEOUT_S,
        )
        self._program = program

    def _host_script(self, call: str, *args: str) -> str:
        arguments = ", ".join([self._key, *(json.dumps(a) for a in args)])
        return f"__cpcc_host.{call}({arguments})"

    def _host(self, call: str, *args: str, timeout: float = HOST_TIMEOUT_S) -> Any:
        return self._isolate.eval(self._host_script(call, *args), timeout_s=timeout)

    def heap_bytes(self) -> int:
        """Bytes of V8 heap this context uses now."""
        return int(self._isolate.heap_stats()["used_heap_size"])

    def _over_heap(self, limit: int) -> bool:
        """Whether the heap is over ``limit`` bytes now (0: no limit)."""
        if limit <= 0:
            return False
        try:
            return self.heap_bytes() > limit
        except Exception:  # an isolate V8 cannot tell about: not a reason to kill the VV
            return False

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
        # More than the one answer the program waits for: it made steps on another host
        # since it ran here, which a resumed run goes through again (a replay's allowance).
        catches_up = len(texts) > 1
        entries = "[" + ",".join(texts) + "]"
        if len(entries) > _APPEND_WITH_STEP_CHARS:
            self._host("append", entries)
            self._appended(texts)
            texts = []
        limits = step.limits
        run = {
            "vvId": step.vv_id,
            "vvName": step.vv_name,
            "seed": step.seed,
            "startMs": step.start_ms,
            "effectsApplied": step.effects_applied,
            "limits": {
                "maxTasks": limits.max_tasks,
                "storageBytes": limits.storage_bytes,
                "pictureBytes": step.picture_bytes,
                "heapBytes": limits.heap_bytes,
                "maxMessages": limits.max_messages,
                "messageBytes": limits.message_bytes,
                "allowedCalls": sorted(limits.allowed_calls)
                if limits.allowed_calls is not None
                else None,
            },
        }
        run_json = json.dumps(run, separators=(",", ":"))
        arguments = (run_json, entries) if texts else (run_json,)
        # A step that resumes where the program waits runs only new work: its CPU quota, less
        # what the VV used since it last waited for the outside world. One that replays also
        # re-runs what the program did before, which has its own allowance.
        allowance = step.cpu_allowance_s
        replay = allowance + 2.0 * step.replay_s + _REPLAY_SLACK_S
        replay_timeout = replay if len(step.journal) else allowance
        # A context that never ran a step has nowhere to resume: it replays.
        resume_timeout = replay if catches_up else allowance
        raw, thrown, killed_by, duration = v8.direct(
            lambda: self._run(
                arguments,
                run_json,
                heap_bytes=limits.heap_bytes,
                resume_timeout=resume_timeout if self._stepped else replay_timeout,
                replay_timeout=replay_timeout,
            )
        )
        self._stepped = True
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
            # V8 stopped the program where it was; what it did before in the step (a
            # callback's storage writes, say) still counts, except after a heap kill (below).
            # The isolate is not used again.
            self.usable = False
        try:
            state = json.loads(raw) if isinstance(raw, str) else None
        except ValueError:
            state = None
        if isinstance(state, dict) and state.get("status") == "stale":
            self.usable = False
            raise StaleContext(self.vv_id)
        if (
            killed is None
            and isinstance(state, dict)
            and state.get("journalLength") != self.journal_length
        ):
            # The outcome is an earlier step's: V8 stopped this call before the program took
            # the answers it was given. A new context replays the step.
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
            if quota == "heap":
                # Stopped for its heap, the program may have been stopped while the outcome
                # was written, or the outcome may not be readable at all: which of its effects
                # survive would depend on the garbage collector. None of this step's do.
                effects, total = (), step.effects_applied
            return StepResult(
                Outcome.KILLED,
                error=VVError(ErrorKind.QUOTA, message, quota=quota),
                effects=effects,
                effects_total=total,
                duration_s=duration,
            )
        return self._interpret(state, thrown, duration)

    def _run(
        self,
        arguments: tuple[str, ...],
        run_json: str,
        *,
        heap_bytes: int,
        resume_timeout: float,
        replay_timeout: float,
    ) -> tuple[Any, str | None, str | None, float]:
        """The step's work in V8, each call from this thread to the isolate's: the outcome's
        text (when there is one), the text of what the program threw, what stopped it
        (``cpu``, ``heap``) and how long it ran."""
        isolate = self._isolate
        isolate.set_hard_memory_limit(heap_bytes)
        raw: Any = None  # the outcome, when the step returns it
        thrown: str | None = None
        killed_by: str | None = None
        started = time.perf_counter()
        try:
            if resume_timeout != replay_timeout:
                # A step that resumes has the CPU quota, one that replays its allowance too.
                raw = self._host("stepIfResumes", *arguments, timeout=resume_timeout)
            if resume_timeout == replay_timeout or raw == _REPLAY:
                raw, started = None, time.perf_counter()  # (None again if the step throws)
                raw = self._host("step", *arguments, timeout=replay_timeout)
        except JSTimeoutException:
            killed_by = "cpu"
        except JSOOMException:
            killed_by = "heap"
        except JSEvalException as exc:
            if isolate.hard_memory_limit_reached() or self._over_heap(heap_bytes):
                # (V8 notes the limit at a garbage collection: a step that filled the heap
                # without one leaves the next call to fail with the heap over its limit.)
                killed_by = "heap"
            else:
                thrown = str(exc)
        duration = time.perf_counter() - started
        if killed_by is None and isolate.hard_memory_limit_reached():
            # The limit was passed after the program's last instruction (the outcome's text
            # of a step that logged megabytes, say): the next call into the isolate would be
            # the one V8 stops. The step ends here, over its quota, with what it did before.
            killed_by = "heap"
        if killed_by is not None:
            isolate.set_hard_memory_limit(0)
            with contextlib.suppress(JSEvalException):
                self._host("abort")
        if not isinstance(raw, str):
            with contextlib.suppress(JSEvalException):
                raw = self._host("outcome")
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

    def _call_site(self, at: Any) -> tuple[int | None, int | None]:
        """The line and column in the user's program of a place the prelude reported (its
        ``callSite``: where in the script that holds the program), or (None, None)."""
        if not (isinstance(at, list) and len(at) == 2 and all(isinstance(n, int) for n in at)):
            return None, None
        line, column = at
        if line == 1:  # the platform's prefix is in front of the program's first line
            column = max(1, column - len(self._program_prefix))
        return line, self._program.user_column(line, column)

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
            "replayed": bool(state.get("replayed", True)),
        }
        status = state["status"]
        fatal = state.get("fatal")
        if status in ("killed", "failed") and isinstance(fatal, dict):
            kind = ErrorKind.QUOTA if status == "killed" else ErrorKind.NONDETERMINISM
            line = column = None
            if thrown is not None:
                _, line, column = self._place(thrown)
            if line is None:  # stopped in the platform's code: where the program called it
                line, column = self._call_site(fatal.get("at"))
            error = VVError(kind, str(fatal.get("message")), line, column, quota=fatal.get("quota"))
            return StepResult(Outcome(status), error=error, **common)
        if status == "suspended":
            pending = PendingRequest.from_json(state["pending"])
            line, column = self._call_site(state["pending"].get("at"))
            if line is not None:
                pending = dataclasses.replace(pending, line=line, column=column)
            return StepResult(Outcome.SUSPENDED, pending=pending, **common)
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
