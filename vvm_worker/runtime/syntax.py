"""V8's verdict on a program's syntax, and reading places out of V8's messages."""

from __future__ import annotations

import asyncio
import re
import sys
from dataclasses import dataclass

from vvm_worker.runtime import v8
from vvm_worker.runtime.instrument import unsupported
from vvm_worker.runtime.memo import TextMemo
from vvm_worker.runtime.v8 import (
    JSEvalException,
    JSOOMException,
    JSParseException,
    JSTimeoutException,
)

PROGRAM_NAME = "vv.js"
CHECK_TIMEOUT_S = 5.0
# A checking isolate keeps the global names of the programs it parsed (below), and the texts
# of the scripts it was given until its garbage collector sees a need (which a heap without a
# limit may not: 200 programs of a million characters were 470 MB): a new one after so many
# programs or so many characters of them keeps that small.
CHECKS_PER_ISOLATE = 500
CHARACTERS_PER_ISOLATE = 16_000_000


@dataclass(frozen=True, slots=True)
class SyntaxProblem:
    """A program V8 cannot parse, or one that uses what a VV program may not (``async``,
    ``await``, ``import()``): the message and where (1-based line and column)."""

    message: str
    line: int
    column: int

    def __str__(self) -> str:
        return f"line {self.line}, column {self.column}: {self.message}"


_LOCATION = re.compile(r"^(?P<res>[^\n]*?):(?P<line>\d+): (?P<msg>[^\n]*)")
_FRAME = re.compile(re.escape(PROGRAM_NAME) + r":(\d+):(\d+)")
_USE_STRICT = re.compile(r"""^(?:\s|//[^\n]*\n|/\*.*?\*/)*(['"])use strict\1""", re.S)


def parse_v8_message(
    text: str, *, parse_error: bool = False, first_line_offset: int = 0
) -> tuple[str, int | None, int | None]:
    """Split a mini-racer exception text into the message and the user's line and column.

    The text is ``RESOURCE:LINE: MESSAGE`` then the source line, a caret under the column and,
    for Error objects, the stack. The place in the program is the thrown-at location when it is
    in the program, otherwise the first stack frame in the program (an API call that threw).
    ``first_line_offset`` is what the platform put in front of the program's first line.
    """
    match = _LOCATION.match(text)
    if match is None:
        return text.strip(), None, None
    message = match.group("msg")
    line: int | None = None
    column: int | None = None
    # A script that does not parse has no name yet: its location is the program's.
    if parse_error or match.group("res").endswith(PROGRAM_NAME):
        lines = text.split("\n")
        line = int(match.group("line"))
        column = lines[2].index("^") + 1 if len(lines) > 2 and "^" in lines[2] else None
    else:
        frame = _FRAME.search(text)
        if frame is not None:
            line, column = int(frame.group(1)), int(frame.group(2))
    if line == 1 and column is not None:
        column = max(1, column - first_line_offset)
    return message, line, column


class _Checker:
    """A warm isolate that parses programs, on the V8 thread, one program at a time.

    Each program is evaluated as a script behind ``throw 0;``: V8 parses the whole script before
    it runs any of it, and the throw stops it before its first statement, so nothing of the
    program runs. What a script leaves in its isolate without running is the names it declares
    at its top level (``var`` and functions on the global object, ``let``/``const``/``class``
    in the script scope). A later program declaring one of them again fails when it would run,
    not when it is parsed, so the verdict is the same as in a new isolate; the isolate is
    replaced every CHECKS_PER_ISOLATE programs or CHARACTERS_PER_ISOLATE characters and after
    a check that V8 had to stop.
    """

    def __init__(self) -> None:
        self._loop: asyncio.AbstractEventLoop | None = None
        self._lock: asyncio.Lock | None = None
        self._isolate: v8.Isolate | None = None
        self._uses = 0
        self._characters = 0

    async def parse_error(self, script: str) -> str | None:
        """V8's text of the script's syntax error, or None when it parses."""
        loop = asyncio.get_running_loop()
        if self._loop is not loop or self._lock is None:  # first use, or a new owner
            self._loop, self._lock, self._isolate = loop, asyncio.Lock(), None
        async with self._lock:
            if (
                self._isolate is None
                or self._uses >= CHECKS_PER_ISOLATE
                or self._characters >= CHARACTERS_PER_ISOLATE
            ):
                if self._isolate is not None:
                    self._isolate.close()
                self._isolate, self._uses, self._characters = await v8.adopt(), 0, 0
            self._uses += 1
            self._characters += len(script)
            try:
                await self._isolate.eval_async(script, timeout_s=CHECK_TIMEOUT_S)
            except JSParseException as exc:
                return str(exc)
            except (JSTimeoutException, JSOOMException):
                self._isolate.close()
                self._isolate = None
            except JSEvalException:  # the throw in front: the program parsed
                pass
        return None


_CHECKER = _Checker()


def _check_syntax(source: str) -> SyntaxProblem | None:
    """``check_syntax``, not remembered."""
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
    script = prefix + body + "\n//# sourceURL=" + PROGRAM_NAME
    text = v8.call(lambda: _CHECKER.parse_error(script))
    if text is None:
        refused = unsupported(source)
        return None if refused is None else SyntaxProblem(*refused)
    message, line, column = parse_v8_message(text, parse_error=True, first_line_offset=len(prefix))
    line = line or 1
    column = column or 1
    lines = source.split("\n")
    if line > len(lines):  # "Unexpected end of input" points past the program's end
        line, column = len(lines), len(lines[-1]) + 1
    return SyntaxProblem(message, line, column)


def _verdict_bytes(problem: SyntaxProblem | None) -> int:
    return 0 if problem is None else 64 + sys.getsizeof(problem.message)


# Verdicts are small: this holds tens of thousands, whatever the programs' sizes.
SYNTAX_CACHE_BYTES = 4 * 1024 * 1024
_VERDICTS: TextMemo[SyntaxProblem | None] = TextMemo(
    _check_syntax, max_bytes=SYNTAX_CACHE_BYTES, size_of=_verdict_bytes
)


def check_syntax(source: str) -> SyntaxProblem | None:
    """V8's verdict on the program's syntax, without running any of it, then what a VV program
    may not use although V8 parses it (``instrument.unsupported``: async functions and
    ``await``, whose continuations would never run, and ``import()``).

    The check evaluates ``throw 0;`` in front of the program on its first line (see
    ``_Checker``). A leading "use strict" directive is kept in front. Safe from any thread.
    Remembered by the program's digest (``memo.TextMemo``, ``SYNTAX_CACHE_BYTES``).
    """
    return _VERDICTS(source)
