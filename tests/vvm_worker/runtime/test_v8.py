"""V8 from many threads, and a process that stops while V8 works (issue 20).

Every isolate of a process is made and closed by one thread (vvm_worker/runtime/v8.py); a
step's scripts are evaluated from the thread that steps the VV, as work a stopping process
waits for.
The crashes this prevents happen in a new process (V8's process-wide set-up) and at its exit,
so the tests run their work in a fresh Python process and judge it by its exit status.
"""

from __future__ import annotations

import asyncio
import logging
import subprocess
import sys
import textwrap
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest

from tests.vvm_worker.runtime.harness import CATALOG, START_MS, Run
from vvm_worker.runtime import Limits, Outcome, Runtime, StepInput, check_syntax, v8

ROOT = Path(__file__).resolve().parents[3]

GPS_TASK = (
    "VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(1, 2, 3), tolerance: 1,"
    " sensors: [VV.sensor.get('GPS')]});"
)


def run_python(code: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)],
        cwd=ROOT,
        env={"PYTHONFAULTHANDLER": "1", "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def assert_clean(result: subprocess.CompletedProcess[str], expected: str) -> None:
    assert result.returncode == 0, result.stderr[-3000:]
    assert expected in result.stdout, (result.stdout, result.stderr[-3000:])
    # A crash in a thread that is not the main one can still leave exit status 0.
    for sign in ("Fatal Python error", "Exception ignored", "Check failed", "Traceback"):
        assert sign not in result.stderr, result.stderr[-3000:]


@pytest.mark.slow
def test_a_new_process_checks_and_steps_from_16_threads_at_once() -> None:
    """Before the owner thread, 16 threads' first checks crashed a new process about one run in
    five (V8's set-up twice at once); three processes in a row must all come through."""
    code = f"""
        from concurrent.futures import ThreadPoolExecutor
        from tests.vvm_worker.runtime.harness import CATALOG, START_MS
        from vvm_worker.runtime import Limits, Outcome, StepInput, check_syntax, run_step

        def check(i):
            ok = check_syntax(f"var x{{i}} = {{i}};\\nVV.log(x{{i}});")
            broken = check_syntax(f"var y{{i}} = ;")
            return ok is None and broken is not None and broken.line == 1

        def step(i):
            result = run_step(StepInput(
                vv_id=f"vv-{{i}}", vv_name="t", source=f"VV.log({{i}});" + {GPS_TASK!r},
                seed=i, start_ms={START_MS}, catalog={CATALOG!r}, journal=[],
                effects_applied=0, limits=Limits(),
            ))
            return result.outcome is Outcome.SUSPENDED

        with ThreadPoolExecutor(16) as pool:
            checks = list(pool.map(check, range(400)))
            steps = list(pool.map(step, range(48)))
        print("checks", sum(checks), "steps", sum(steps))
    """
    for _ in range(3):
        assert_clean(run_python(code), "checks 400 steps 48")


@pytest.mark.slow
def test_a_process_that_exits_while_a_step_runs_lets_it_finish_and_exits_0() -> None:
    """The interpreter's exit waits for the step in progress in another thread (before, the
    exit closed the isolate under it: the step was lost, its callback into Python called into
    a closed loop), then closes every isolate on the V8 thread."""
    code = f"""
        import atexit, threading
        from tests.vvm_worker.runtime.harness import CATALOG, START_MS
        from vvm_worker.runtime import Limits, Runtime, StepInput, answer_task, v8

        # Registered before V8's own exit hook, so it runs after it: once V8's hook has let
        # the step's script end, the thread reports what the step came to before the
        # interpreter finalizes (a daemon thread still printing then crashes the process).
        workers = []
        atexit.register(lambda: [thread.join(30) for thread in workers])
        runtime = Runtime()
        source = {GPS_TASK!r} + "var x = 0; for (var i = 0; i < 2e9; i++) x += i;" + {GPS_TASK!r}

        def step(journal, applied):
            return runtime.step(StepInput(
                vv_id="busy", vv_name="b", source=source, seed=1, start_ms={START_MS},
                catalog={CATALOG!r}, journal=journal, effects_applied=applied,
                limits=Limits(cpu_s=20)))

        first = step([], 0)  # quick: makes the warm context
        answer = answer_task(first.pending, time_ms={START_MS}, data=[None])
        started = threading.Event()

        def work():
            started.set()
            result = step([answer], first.effects_total)  # the long one
            print("step:", result.outcome.value, flush=True)

        workers.append(threading.Thread(target=work, daemon=True))
        workers[0].start()
        started.wait()
        while v8.busy() == 0:  # until the long step is in V8
            pass
        print("main: exit", flush=True)
    """
    result = run_python(code)
    assert_clean(result, "main: exit\nstep: suspended")


def test_syntax_checks_from_many_threads_give_each_program_its_own_verdict() -> None:
    programs = [f"var a{n} = {n};\nlet b{n} = a{n};" for n in range(64)]
    programs += [f"let c{n} = 1;\nlet c{n} = 2;" for n in range(32)]  # redeclared: line 2
    with ThreadPoolExecutor(16) as pool:
        verdicts = list(pool.map(check_syntax, programs))
    assert verdicts[:64] == [None] * 64
    assert all(v is not None and v.line == 2 for v in verdicts[64:]), verdicts[64:]


def test_a_warm_checker_gives_a_program_the_verdict_of_a_new_isolate() -> None:
    """The checking isolate keeps the top-level names of the programs it parsed; a program that
    declares them again is still valid (its names are its own when it runs)."""
    assert check_syntax("let shared = 1; var other = 2; class K {}") is None
    assert check_syntax("let shared = 3; let other = 4; const K = 5;") is None
    problem = check_syntax("var ok = 1;\nvar = 2;")
    assert problem is not None and (problem.line, problem.column) == (2, 5)


def test_steps_of_many_vvs_from_many_threads_match_one_thread() -> None:
    source = "var k = 0; while (k < 3) { VV.storage.store('k' + k, Math.random()); " + (
        GPS_TASK + " k++; }"
    )

    def drive(seed: int) -> dict:
        run = Run(source=source, seed=seed)
        assert run.run().outcome is Outcome.FINISHED
        return run.storage

    alone = [drive(seed) for seed in range(12)]
    with ThreadPoolExecutor(12) as pool:
        together = list(pool.map(drive, range(12)))
    assert together == alone


def test_each_thread_keeps_its_warm_contexts() -> None:
    """Runtimes in two threads at once (a worker's Celery thread and its vehicle's)."""
    failures: list[BaseException] = []

    def drive(name: str) -> None:
        runtime = Runtime()
        try:
            for _ in range(20):
                result = runtime.step(
                    StepInput(
                        vv_id=name,
                        vv_name=name,
                        source=GPS_TASK,
                        seed=1,
                        start_ms=START_MS,
                        catalog=CATALOG,
                        journal=[],
                        effects_applied=0,
                        limits=Limits(),
                    )
                )
                assert result.outcome is Outcome.SUSPENDED
                assert runtime.context(name) is not None
        except BaseException as exc:
            failures.append(exc)
        finally:
            runtime.close()

    threads = [threading.Thread(target=drive, args=(f"t{n}",)) for n in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not failures, failures


def test_after_shutdown_every_isolate_is_closed_and_v8_refuses_work() -> None:
    code = f"""
        from vvm_worker.runtime import Limits, Runtime, StepInput, v8
        from tests.vvm_worker.runtime.harness import CATALOG, START_MS

        runtime = Runtime()
        for n in range(3):
            runtime.step(StepInput(vv_id=f"vv{{n}}", vv_name="s", source={GPS_TASK!r}, seed=1,
                                   start_ms={START_MS}, catalog={CATALOG!r}, journal=[],
                                   effects_applied=0, limits=Limits()))
        print("open before:", v8.open_isolates() >= 3)
        v8.shutdown()
        print("open after:", v8.open_isolates())
        try:
            v8.new_isolate()
        except v8.V8Closed as exc:
            print("refused:", exc)
        runtime.close()  # closing what the shutdown closed already is harmless
    """
    result = run_python(code)
    assert_clean(result, "open before: True\nopen after: 0\nrefused: V8 is shut down")


def test_the_v8_thread_owns_every_isolate() -> None:
    isolate = v8.new_isolate()
    try:
        owner = isolate.eval("1 + 1", timeout_s=5)
        assert owner == 2
        assert "cpcc-v8" in {t.name for t in threading.enumerate()}
    finally:
        isolate.close()
    assert isolate.closed


def test_closing_an_isolate_from_another_thread_does_not_wait_for_the_v8_thread() -> None:
    """A worker that lets a VV's context go does not wait while the V8 thread is busy; the
    isolate is freed after the work queued before it."""
    isolate, other = v8.new_isolate(), v8.new_isolate()
    before = v8.open_isolates()
    busy, release = threading.Event(), threading.Event()

    async def hold() -> None:  # the V8 thread's loop, held
        busy.set()
        release.wait(10)

    holder = threading.Thread(target=lambda: v8.call(hold))
    holder.start()
    assert busy.wait(10)
    isolate.close()  # returns although the V8 thread cannot free it now
    assert isolate.closed and v8.open_isolates() == before
    release.set()
    holder.join(10)
    assert other.eval("1 + 1", timeout_s=5) == 2

    async def nothing() -> None:
        pass

    v8.call(nothing)  # after the close queued before it, on the same loop
    assert v8.open_isolates() == before - 1
    other.close()


def test_a_script_over_its_time_is_stopped_and_its_isolate_answers_the_next_one() -> None:
    """Scripts run from the caller's thread: one over its time is terminated by V8 (the
    caller learns it at its timeout), while a script of another isolate, from another thread,
    is answered meanwhile; the stopped isolate's next script gets its own value."""
    looping, other = v8.new_isolate(), v8.new_isolate()
    answered: list[object] = []

    def meanwhile() -> None:
        answered.extend(other.eval(f"{n} * 2", timeout_s=5) for n in range(20))

    try:
        helper = threading.Thread(target=meanwhile)
        started = time.perf_counter()
        helper.start()
        with pytest.raises(v8.JSTimeoutException):
            looping.eval("var x = 0; while (true) { x++; }", timeout_s=0.3)
        assert time.perf_counter() - started >= 0.3
        helper.join(10)
        assert answered == [n * 2 for n in range(20)]
        assert looping.eval("'next ' + 1", timeout_s=5) == "next 1"
        assert looping.eval("x > 0", timeout_s=5) is True  # the stopped script's global
    finally:
        looping.close()
        other.close()


def test_a_pool_filled_ahead_gives_isolates_without_preparing_them_when_taken(
    monkeypatch,
) -> None:
    from vvm_worker.runtime import pool as pool_module

    pool = pool_module.IsolatePool(3)
    pool.fill()

    def ready() -> int:  # read on the V8 thread, which fills the pool
        return v8.call(lambda: _count(pool))

    deadline = time.monotonic() + 30
    while ready() < 3:
        assert time.monotonic() < deadline, "the pool was not filled"
        time.sleep(0.05)

    async def refused() -> pool_module.Prepared:
        raise AssertionError("prepared when taken")

    monkeypatch.setattr(pool_module, "prepare", refused)
    pool.size = 0  # nothing prepared after these
    taken = [pool.take() for _ in range(3)]
    assert len({id(p.isolate) for p in taken}) == 3
    for prepared in taken:
        prepared.isolate.close()


def test_a_pool_prepares_isolates_side_by_side_and_keeps_those_made_when_one_fails(
    monkeypatch, caplog
) -> None:
    """A burst of new VVs takes isolates faster than one preparation after the other makes
    them: the pool prepares FILL_AT_ONCE at a time. One that fails loses only itself."""
    from vvm_worker.runtime import pool as pool_module

    real = pool_module.prepare
    calls, running, most = 0, 0, 0
    together: list[asyncio.Event] = []

    async def prepare() -> pool_module.Prepared:
        nonlocal calls, running, most
        calls += 1
        call = calls
        running += 1
        most = max(most, running)
        if not together:
            together.append(asyncio.Event())
        if running == pool_module.FILL_AT_ONCE:
            together[0].set()
        try:
            # The first preparations wait for each other: made one at a time, they never meet.
            await asyncio.wait_for(together[0].wait(), 10)
            if call == 3:
                raise RuntimeError("this one fails")
            return await real()
        finally:
            running -= 1

    monkeypatch.setattr(pool_module, "prepare", prepare)
    pool = pool_module.IsolatePool(4)
    with caplog.at_level(logging.ERROR, logger="vvm_worker.runtime.pool"):
        pool.fill()
        deadline = time.monotonic() + 30
        while v8.call(lambda: _filling(pool)):
            assert time.monotonic() < deadline, "the pool did not stop filling"
            time.sleep(0.05)
    assert pool_module.FILL_AT_ONCE >= 2 and most == pool_module.FILL_AT_ONCE
    ready = v8.call(lambda: _count(pool))
    assert (calls, ready) == (4, 3)  # the second pair: one failed, the other is kept
    assert "isolates could not be prepared ahead of time" in caplog.text
    monkeypatch.setattr(pool_module, "prepare", real)
    pool.size = 0
    for _ in range(ready):
        pool.take().isolate.close()


async def _filling(pool) -> bool:  # type: ignore[no-untyped-def]
    return pool._filling is not None


async def _count(pool) -> int:  # type: ignore[no-untyped-def]
    return len(pool._ready)


def test_work_that_needs_an_isolate_is_told_when_one_is_prepared(monkeypatch) -> None:
    """A host thread does not wait for V8 to make an isolate: it is told once one is."""
    from vvm_worker.runtime import pool as pool_module

    assert not pool_module.IsolatePool(0).notify_when_ready(lambda: None)  # none ahead
    pool = pool_module.IsolatePool(2)
    told = threading.Event()
    assert pool.notify_when_ready(told.set)  # none prepared: it prepares one
    assert told.wait(30), "not told"
    assert v8.call(lambda: _count(pool)) >= 1
    assert not pool.notify_when_ready(lambda: None)  # one is there: take it

    async def refused() -> pool_module.Prepared:
        raise AssertionError("prepared when taken")

    monkeypatch.setattr(pool_module, "prepare", refused)
    pool.size = 0
    pool.take().isolate.close()
    for _ in range(v8.call(lambda: _count(pool))):
        pool.take().isolate.close()


def test_work_told_that_preparing_failed_makes_its_own_isolate_and_meets_the_error(
    monkeypatch, caplog
) -> None:
    from vvm_worker.runtime import pool as pool_module

    async def broken() -> pool_module.Prepared:
        raise RuntimeError("V8 is out of memory")

    monkeypatch.setattr(pool_module, "prepare", broken)
    pool = pool_module.IsolatePool(2)
    told = threading.Event()
    with caplog.at_level(logging.ERROR, logger="vvm_worker.runtime.pool"):
        assert pool.notify_when_ready(told.set)
        assert told.wait(30), "not told that preparing failed"
        deadline = time.monotonic() + 30
        while v8.call(lambda: _filling(pool)):
            assert time.monotonic() < deadline, "the pool did not stop filling"
            time.sleep(0.05)
    # Nothing to wait for: the work goes on, and its own preparation gives it the error.
    assert not pool.notify_when_ready(lambda: None)
    with pytest.raises(RuntimeError, match="out of memory"):
        pool.take()
