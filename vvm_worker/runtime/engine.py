"""Running the steps of virtual vehicles in V8 (mini-racer): resumed where they wait, or
replayed.

``Runtime`` keeps one warm context (context.py) per VV while the VV stays on this host and
sends each step only the journal entries the context does not have yet; ``run_step`` runs one
step in a context made for it. The parts: v8.py (the thread that owns V8), syntax.py (V8's
verdict on a program), instrument.py (the program as the platform runs it), pool.py (isolates
with the prelude), context.py (one VV's isolate and a step in it), answers.py (the journal
entries the host writes).

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

from collections import OrderedDict

from vvm_worker.runtime.context import StaleContext, VVContext
from vvm_worker.runtime.instrument import ReservedNameError
from vvm_worker.runtime.syntax import check_syntax
from vvm_worker.runtime.types import ErrorKind, Outcome, StepInput, StepResult, VVError


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
