"""Instrumenting a VV program so that a suspended step unwinds through the program's own code.

A step ends by throwing an internal marker from the pending VVM-API call. As blocking code,
the program never sees that call return, so its own ``catch`` clauses must not swallow the
marker and its ``finally`` clauses must not run. The program is rewritten once when it is
loaded (tree-sitter-javascript gives exact positions):

    catch (e) { BODY }    ->  catch (e) { __cpcc_rethrow(e); BODY }
    catch { BODY }        ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); BODY }
    catch ({a, b}) { .. } ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); let {a, b} = __cpcc_e; .. }
    finally { BODY }      ->  finally { if (!__cpcc_suspended()) { BODY } }

Insertions never contain a newline, so line numbers in error messages stay the user's.
Identifiers starting with ``__cpcc`` are reserved for these hooks.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache

import tree_sitter_javascript
from tree_sitter import Language, Node, Parser

RESERVED_PREFIX = "__cpcc"
_RESERVED = re.compile(r"__cpcc\w*")

_LANGUAGE = Language(tree_sitter_javascript.language())


class ReservedNameError(ValueError):
    """The program uses an identifier reserved for the platform."""

    def __init__(self, name: str, line: int, column: int) -> None:
        super().__init__(
            f"line {line}, column {column}: the name {name!r} is reserved for the platform "
            f"(names starting with {RESERVED_PREFIX!r} may not be used)"
        )
        self.line = line
        self.column = column


@dataclass(frozen=True, slots=True)
class _Insert:
    offset: int  # byte offset in the UTF-8 source
    text: bytes
    replace_to: int | None = None  # when set, bytes offset..replace_to are replaced


def _find_reserved(source: str) -> None:
    match = _RESERVED.search(source)
    if match is None:
        return
    before = source[: match.start()]
    line = before.count("\n") + 1
    column = match.start() - (before.rfind("\n") + 1) + 1
    raise ReservedNameError(match.group(0), line, column)


def _walk(node: Node) -> list[Node]:
    found: list[Node] = []
    stack = [node]
    while stack:
        current = stack.pop()
        if current.type in ("catch_clause", "finally_clause"):
            found.append(current)
        stack.extend(current.children)
    return found


def _catch_inserts(clause: Node) -> list[_Insert]:
    body = clause.child_by_field_name("body")
    if body is None or body.type != "statement_block":
        return []
    after_brace = body.start_byte + 1
    param = clause.child_by_field_name("parameter")
    if param is None:
        # `catch {` or `catch{`: give the clause a binding.
        return [
            _Insert(body.start_byte, b"(__cpcc_e) "),
            _Insert(after_brace, b" __cpcc_rethrow(__cpcc_e);"),
        ]
    if param.type == "identifier":
        name = param.text or b""
        return [_Insert(after_brace, b" __cpcc_rethrow(" + name + b");")]
    pattern = param.text or b""
    if b"\n" in pattern:
        pattern = b" ".join(pattern.split())
    return [
        _Insert(param.start_byte, b"__cpcc_e", replace_to=param.end_byte),
        _Insert(after_brace, b" __cpcc_rethrow(__cpcc_e); let " + pattern + b" = __cpcc_e;"),
    ]


def _finally_inserts(clause: Node) -> list[_Insert]:
    body = clause.child_by_field_name("body")
    if body is None:
        body = next((c for c in clause.children if c.type == "statement_block"), None)
    if body is None:
        return []
    return [
        _Insert(body.start_byte + 1, b" if (!__cpcc_suspended()) {"),
        _Insert(body.end_byte - 1, b"} "),
    ]


@lru_cache(maxsize=256)
def instrument(source: str) -> str:
    """The program with its catch and finally clauses instrumented (see the module docstring).

    Raises ReservedNameError when the program uses a reserved identifier. Syntax is checked by
    V8 before this is called; a clause tree-sitter cannot parse is left as it is.
    """
    _find_reserved(source)
    data = source.encode("utf-8")
    tree = Parser(_LANGUAGE).parse(data)
    inserts: list[_Insert] = []
    for clause in _walk(tree.root_node):
        if clause.has_error:
            continue
        if clause.type == "catch_clause":
            inserts.extend(_catch_inserts(clause))
        else:
            inserts.extend(_finally_inserts(clause))
    if not inserts:
        return source
    # Apply from the end so earlier offsets stay valid; at one offset, the insert listed first
    # must end up first, so it is applied last.
    out = data
    ordered = sorted(enumerate(inserts), key=lambda pair: (pair[1].offset, pair[0]))
    for _, ins in reversed(ordered):
        end = ins.replace_to if ins.replace_to is not None else ins.offset
        out = out[: ins.offset] + ins.text + out[end:]
    return out.decode("utf-8")
