"""How much the suite checks, counted in its source: ``python -m tests.assertions [--files]``.

Counted in every Python file under tests/: ``assert`` statements, and calls of the checking
helpers: pytest's ``raises``/``warns``/``fail``, Playwright's ``expect(...)``, the waits that fail
when their condition never holds (``wait_for``, ``wait_until``, ...), and every function or method
whose name starts with ``assert`` or ``check_`` (``traffic.assert_clean()``, say). A change that
merges tests keeps this number (docs/testing.md records it before and after).
"""

from __future__ import annotations

import ast
import sys
from collections import Counter
from pathlib import Path

TESTS = Path(__file__).resolve().parent
HELPERS = {
    "raises",
    "warns",
    "fail",
    "expect",
    "wait_for",
    "wait_until",
    "wait_until_async",
    "eventually",
    "wait_for_log",
}


def called_name(node: ast.Call) -> str:
    function = node.func
    if isinstance(function, ast.Attribute):
        return function.attr
    if isinstance(function, ast.Name):
        return function.id
    return ""


def kind(node: ast.AST) -> str | None:
    """What kind of check ``node`` is, or None."""
    if isinstance(node, ast.Assert):
        return "assert"
    if isinstance(node, ast.Call):
        name = called_name(node)
        if name in HELPERS:
            return name
        if name.startswith(("assert", "check_")):
            return "assert...()"
    return None


def count(path: Path) -> Counter[str]:
    found: Counter[str] = Counter()
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        name = kind(node)
        if name is not None:
            found[name] += 1
    return found


def main(argv: list[str]) -> None:
    total: Counter[str] = Counter()
    for path in sorted(TESTS.rglob("*.py")):
        found = count(path)
        total += found
        if "--files" in argv and found:
            print(f"{sum(found.values()):6d}  {path.relative_to(TESTS.parent)}")
    parts = ", ".join(f"{name} {n}" for name, n in total.most_common())
    print(f"{sum(total.values())} checks: {parts}")


if __name__ == "__main__":
    main(sys.argv[1:])
