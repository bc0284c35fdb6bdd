"""One limit on how deeply JSON may nest, for everything customers send: request bodies (the
REST API's parser, the pages' JSON endpoints), the map socket's messages, and the values a VV
stores (vvm_worker/services/vvs.py).

Python's JSON parser and encoder, and every function that walks a value recursively (rendering
a page, finding camera readings in it), recurse once per level: a value far deeper than any
real data needs would exhaust the interpreter's recursion limit (1,000 frames) in one of them
and turn into a server error. The limit keeps every value far below it.
"""

from __future__ import annotations

import json
from typing import Any

# How deeply a JSON value may nest (arrays and objects in one another): far below Python's
# recursion limit, which parsing it here and on every later read of the document must stay
# clear of.
MAX_VALUE_DEPTH = 100


class TooDeep(ValueError):
    """A JSON text or value nests more than MAX_VALUE_DEPTH levels."""


def too_deep(value: Any) -> bool:
    """Whether a parsed JSON value nests arrays and objects more than MAX_VALUE_DEPTH levels.
    Walks the value with a list, not by recursion, however deep it is."""
    todo: list[tuple[Any, int]] = [(value, 0)]
    while todo:
        item, depth = todo.pop()
        if isinstance(item, list | dict):
            if depth >= MAX_VALUE_DEPTH:
                return True
            children = item if isinstance(item, list) else item.values()
            todo.extend((child, depth + 1) for child in children)
    return False


def loads(text: str | bytes) -> Any:
    """The value of a JSON text. Raises TooDeep when it nests more than MAX_VALUE_DEPTH levels
    (however deep: the parser's RecursionError is one too), ValueError when it is not JSON."""
    try:
        value = json.loads(text)
    except RecursionError:  # deeper than the parser's recursion goes
        raise TooDeep(too_deep_message()) from None
    if too_deep(value):
        raise TooDeep(too_deep_message())
    return value


def too_deep_message(what: str = "The JSON") -> str:
    """What a person is told about a value nested too deeply."""
    return (
        f"{what} is nested more than {MAX_VALUE_DEPTH} levels deep (arrays and objects in one "
        "another): send a flatter value."
    )
