"""What a process remembers of the programs it checked and instrumented (vvm_worker/runtime/
memo.py): keyed by a digest, bounded by bytes, so that many large programs sent to the web
(a dry run, a submission) cannot fill its memory."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from vvm_worker.runtime.memo import ENTRY_BYTES, TextMemo

ROOT = Path(__file__).resolve().parents[3]
# README's security section states these bounds.
SYNTAX_CHECKS_GROWTH_MB = 200
INSTRUMENTED_GROWTH_MB = 100


def test_what_is_remembered_is_bounded_by_bytes_least_recently_used_first_out() -> None:
    computed: list[str] = []

    def length(text: str, times: int) -> str | None:
        computed.append(text)
        if text == "bad":
            raise ValueError("bad")
        return None if text == "none" else text * times

    memo = TextMemo(length, max_bytes=3 * (ENTRY_BYTES + 100), size_of=lambda v: len(v or ""))
    for text in ("a" * 100, "b" * 100, "c" * 100):
        assert memo(text, 1) == text
    assert memo("a" * 100, 1) == "a" * 100 and len(computed) == 3  # remembered
    assert memo("a" * 100, 2) == "a" * 200 and len(computed) == 4  # another extra, another key
    assert len(memo) == 2 and memo.held_bytes == 2 * ENTRY_BYTES + 300  # "b" went, then "c"
    memo("b" * 100, 1)
    memo("a" * 100, 2)
    assert len(computed) == 5, "the least recently used went first (the first 'a', not this)"
    # Nothing is remembered of a value larger than the whole bound, nor of an exception; an
    # answer of None is.
    memo("d" * 1000, 1)
    memo("d" * 1000, 1)
    with pytest.raises(ValueError, match="bad"):
        memo("bad", 1)
    with pytest.raises(ValueError, match="bad"):
        memo("bad", 1)
    assert memo("none", 1) is None and memo("none", 1) is None
    assert computed[5:] == ["d" * 1000, "d" * 1000, "bad", "bad", "none"]
    assert memo.held_bytes <= memo.max_bytes


def test_many_large_distinct_programs_leave_a_process_within_its_bound() -> None:
    # The probe: 200 different programs of a million characters with a syntax error
    # (an emoji each, so Python keeps 4 bytes a character) took a web process from 214 MB to
    # 1,446 MB for good, and instrumenting 200 programs of 250,000 characters 380 MB more.
    probe = textwrap.dedent(
        """
        import gc
        from vvm_worker.runtime.instrument import instrument_program
        from vvm_worker.runtime.syntax import check_syntax

        def rss_mb():
            with open("/proc/self/status") as status:
                for line in status:
                    if line.startswith("VmRSS:"):
                        return int(line.split()[1]) / 1024

        check_syntax("var warm = 1;")
        instrument_program("var warm = 1;")
        gc.collect()
        start = rss_mb()
        for n in range(200):
            problem = check_syntax("\\U0001F600" + f"{n:07d}" + "x" * 999_992)
            assert problem is not None and (problem.line, problem.column) == (1, 1), problem
        gc.collect()
        checked = rss_mb()
        for n in range(200):
            program = f"// \\U0001F600 {n:07d} " + "x" * 250_000 + "\\nVV.task.execute({});\\n"
            assert instrument_program(program).generator
        gc.collect()
        print(round(checked - start), round(rss_mb() - checked))
        """
    )
    done = subprocess.run(
        [sys.executable, "-c", probe], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert done.returncode == 0, done.stderr
    checks_mb, instrumented_mb = map(int, done.stdout.split())
    assert checks_mb < SYNTAX_CHECKS_GROWTH_MB, f"the syntax checks grew it by {checks_mb} MB"
    assert instrumented_mb < INSTRUMENTED_GROWTH_MB, (
        f"instrumenting grew it by {instrumented_mb} MB"
    )
