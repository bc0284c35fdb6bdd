"""What the database can keep of a VV's values: the checks of a stored value, a log line and a
message, each failing with what is wrong and where."""

from __future__ import annotations

import json
from typing import Any

from cpcc_site.json_depth import MAX_VALUE_DEPTH  # how deeply a stored value may nest


class Unstorable(ValueError):
    """A value (an effect of a step, a message) that the database cannot store, with what is
    wrong and where."""


def check_text(text: str, *, where: str) -> None:
    """Raise Unstorable for a string that no database column takes: PostgreSQL stores no
    U+0000 (in text or in a JSON value), and no UTF-8 encodes a lone UTF-16 surrogate."""
    nul = text.find("\x00")
    if nul >= 0:
        raise Unstorable(f"{where} has the character U+0000 (character {nul + 1})")
    try:
        text.encode()
    except UnicodeEncodeError as exc:
        raise Unstorable(
            f"{where} has a lone UTF-16 surrogate (character {exc.start + 1})"
        ) from None


def json_value(text: str, *, where: str) -> Any:
    """The value of a JSON text, checked for what the database cannot store; Unstorable if
    it is not JSON, nests deeper than MAX_VALUE_DEPTH or holds a string check_text refuses.
    The check walks the value with a list, not by recursion, however deep it is."""
    try:
        value = json.loads(text)
    except RecursionError:  # deeper than the parser's recursion goes
        raise Unstorable(f"{where} nests more than {MAX_VALUE_DEPTH} levels deep") from None
    except ValueError as exc:
        raise Unstorable(f"{where} is not valid JSON ({exc})") from None
    # The walk runs for every value a step stores: only when the text could hide what it looks
    # for (a string with U+0000 or a surrogate comes from a \u escape or a non-ASCII text; more
    # levels than the limit take more opening brackets).
    escapes = "\\u" in text or not text.isascii()
    if not escapes and text.count("[") + text.count("{") <= MAX_VALUE_DEPTH:
        return value
    todo: list[tuple[Any, int]] = [(value, 0)]
    while todo:
        item, depth = todo.pop()
        if isinstance(item, str):
            check_text(item, where=f"a string in {where}")
        elif isinstance(item, list | dict):
            if depth >= MAX_VALUE_DEPTH:
                raise Unstorable(f"{where} nests more than {MAX_VALUE_DEPTH} levels deep")
            children = item if isinstance(item, list) else [*item, *item.values()]
            todo.extend((child, depth + 1) for child in children)
    return value
