"""Instrumenting a VV program so that a suspended step unwinds through the program's own code.

A step ends by throwing an internal marker from the pending VVM-API call. As blocking code,
the program never sees that call return, so its own ``catch`` clauses must not swallow the
marker and its ``finally`` clauses must not run. The program is rewritten once when it is
loaded (tree-sitter-javascript gives exact positions):

    catch (e) { BODY }    ->  catch (e) { __cpcc_rethrow(e); BODY }
    catch { BODY }        ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); BODY }
    catch ({a, b}) { .. } ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); let {a, b} = __cpcc_e; .. }
    finally { BODY }      ->  finally { if (!__cpcc_suspended()) { BODY } }

Insertions never contain a newline, so line numbers in error messages stay the user's;
``Instrumented.user_column`` takes a column back to the user's. Identifiers starting with
``__cpcc`` are reserved for these hooks.

A program is also made *suspendable* when it can be (``instrument_program``): compiled as a
generator function, with each call of ``VV.task.execute`` / ``VV.task.executeAll`` in its own
body waiting by ``yield*``:

    VV.task.execute(ARGS)     ->  (yield* __cpcc_execute(ARGS))

and so is each such call in a *helper*, a function declared at the program's top level that is
only ever called (never used as a value, never rebound, no ``arguments``) from the program's
body or another helper: the helper becomes ``function*`` and its calls ``(yield* f(ARGS))``.
Between steps the program then stays suspended at the call (engine.py and prelude.js resume it
there). A call anywhere else, in a callback or a function used as a value, still ends the step
the replay way. The rewrite changes nothing a program can observe, which is why it is only
made when ``VV`` is the platform's (the program never binds the name, nor uses ``with``) and
the program does not use ``yield`` (a keyword in a generator).
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


@dataclass(frozen=True, slots=True)
class Instrumented:
    """A program as the platform runs it."""

    code: str
    generator: bool  # compile as ``function*``: the program waits at its call sites by yielding
    # Per line (1-based), the inserts made in it, by column: (first and one-past-last column
    # of the inserted text in ``code``, characters it added, characters it replaced).
    shifts: tuple[tuple[int, tuple[tuple[int, int, int, int], ...]], ...] = ()

    def user_column(self, line: int, column: int) -> int:
        """The user's column for ``column`` (1-based) of ``line`` in ``code``: a place in an
        inserted text is the same place in the text it replaced (or where it was inserted)."""
        for shifted_line, inserts in self.shifts:
            if shifted_line != line:
                continue
            added = 0
            for start, end, grew, replaced in inserts:
                if column >= end:
                    added += grew
                elif column >= start:
                    return start - added + min(column - start, max(replaced - 1, 0))
                else:
                    break
            return max(1, column - added)
        return column


# Where a call site is inside a function of the program's own, `yield` would not be allowed.
_NESTED = frozenset(
    {
        "function_declaration",
        "function_expression",
        "generator_function_declaration",
        "generator_function",
        "arrow_function",
        "method_definition",
        "class_declaration",
        "class",
    }
)
_SUSPENDING = {b"VV.task.execute": b"__cpcc_execute", b"VV.task.executeAll": b"__cpcc_executeAll"}
_NAMES = frozenset(
    {
        "identifier",
        "shorthand_property_identifier",
        "shorthand_property_identifier_pattern",
        "statement_identifier",
    }
)


def _plain_call(node: Node) -> Node | None:
    """The callee of ``node`` when it is a call ``f(...)`` (not ``f?.()``, not a tagged
    template)."""
    if node.type != "call_expression":
        return None
    arguments = node.child_by_field_name("arguments")
    if arguments is None or arguments.type != "arguments":
        return None
    if any(c.type == "optional_chain" for c in node.children):
        return None
    return node.child_by_field_name("function")


_TOP = b""  # where a call is: in the program's own body


def _call_sites(root: Node) -> list[_Insert] | None:
    """The inserts turning the program's waiting calls into ``yield*``, or None when the
    program cannot be made a generator unnoticed (see the module docstring).

    The calls of execute/executeAll in the program's own body become ``yield*`` calls of the
    hooks. So do those in the body of a *helper*, a function declared at the top level that is
    only ever called (never used as a value nor given another binding, and not using
    ``arguments``), which then becomes a generator, and so do the calls of such a helper where
    they are in the program's body or in another one's.
    """
    if root.has_error:
        return None
    helpers: dict[bytes, Node] = {}
    unusable: set[bytes] = set()
    for child in root.children:
        declared = child.child_by_field_name("name")
        if (
            child.type == "function_declaration"
            and not any(c.type == "async" for c in child.children)
            and declared is not None
            and declared.text
        ):
            if declared.text in helpers:
                unusable.add(declared.text)  # declared twice
            helpers[declared.text] = child
    by_node = {node.id: name for name, node in helpers.items()}
    # Where each waiting call and each call of a helper is: _TOP, the name of the helper in
    # whose own body it is, or None (in a function or class of its own, or in parameters).
    waits: list[tuple[Node, bytes | None]] = []
    calls: list[tuple[Node, bytes, bytes | None]] = []
    # (node, where it is, the helper whose declaration holds it at any depth)
    stack: list[tuple[Node, bytes | None, bytes | None]] = [(root, _TOP, None)]
    while stack:
        node, where, within = stack.pop()
        kind = node.type
        if kind in _NAMES:
            text = node.text or b""
            parent = node.parent
            if text == b"yield":
                return None
            if text == b"VV" and (
                kind != "identifier"
                or parent is None
                or parent.type != "member_expression"
                or parent.child_by_field_name("object") != node
            ):
                return None
            if text == b"arguments" and within is not None:
                unusable.add(within)  # an arrow function inside sees the helper's arguments
            if text in helpers and node != helpers[text].child_by_field_name("name"):
                if parent is not None and _plain_call(parent) == node:
                    calls.append((parent, text, where))
                else:
                    unusable.add(text)
        elif kind == "with_statement":
            return None
        callee = _plain_call(node)
        if callee is not None and callee.text in _SUSPENDING and where is not None:
            waits.append((node, where))
        helper = by_node.get(node.id) if where == _TOP else None
        if helper is not None:
            body = node.child_by_field_name("body")
            for child in node.children:
                stack.append((child, helper if child == body else None, helper))
        else:
            below = None if kind in _NESTED else where
            stack.extend((child, below, within) for child in node.children)
    # The helpers that become generators: those that wait (in their own body, or by calling
    # one that does) and are called only where a `yield` can be.
    chosen = set(helpers) - unusable
    while True:
        waiting: set[bytes] = set()
        grown = True
        while grown:
            grown = False
            for name in chosen - waiting:
                if any(w == name for _, w in waits) or any(
                    w == name and c in waiting for _, c, w in calls
                ):
                    waiting.add(name)
                    grown = True
        kept = {
            name
            for name in waiting
            if all(w == _TOP or w in waiting for _, c, w in calls if c == name)
        }
        if kept == chosen:
            break
        chosen = kept
    inserts: list[_Insert] = []
    for name in chosen:
        keyword = next(c for c in helpers[name].children if c.type == "function")
        inserts.append(_Insert(keyword.end_byte, b"*"))
    sites = [call for call, w in waits if w == _TOP or w in chosen]
    sites += [call for call, name, _ in calls if name in chosen]
    for call in sites:
        callee = _plain_call(call)
        assert callee is not None and callee.text is not None
        target = _SUSPENDING.get(callee.text, callee.text)
        inserts.append(_Insert(callee.start_byte, b"(yield* " + target, replace_to=callee.end_byte))
        inserts.append(_Insert(call.end_byte, b")"))
    return inserts


def _apply(data: bytes, inserts: list[_Insert], *, generator: bool) -> Instrumented:
    """``data`` with ``inserts`` made, and where they moved the columns."""
    out = data
    # Apply from the end so earlier offsets stay valid; at one offset, the insert listed first
    # must end up first, so it is applied last.
    ordered = sorted(enumerate(inserts), key=lambda pair: (pair[1].offset, pair[0]))
    for _, ins in reversed(ordered):
        end = ins.replace_to if ins.replace_to is not None else ins.offset
        out = out[: ins.offset] + ins.text + out[end:]
    code = out.decode("utf-8")
    shifts: dict[int, list[tuple[int, int, int, int]]] = {}
    moved = 0  # bytes added before the current insert, in the output
    for _, ins in ordered:
        end = ins.replace_to if ins.replace_to is not None else ins.offset
        start_out = ins.offset + moved
        moved += len(ins.text) - (end - ins.offset)
        line_start = out.rfind(b"\n", 0, start_out) + 1
        line = out.count(b"\n", 0, start_out) + 1
        column = len(out[line_start:start_out].decode("utf-8")) + 1
        text = len(ins.text.decode("utf-8"))
        replaced = len(data[ins.offset : end].decode("utf-8"))
        shifts.setdefault(line, []).append((column, column + text, text - replaced, replaced))
    return Instrumented(
        code, generator, tuple((line, tuple(moves)) for line, moves in sorted(shifts.items()))
    )


@lru_cache(maxsize=256)
def instrument_program(source: str, *, suspendable: bool = True) -> Instrumented:
    """The program with its catch and finally clauses instrumented and, when it can be and
    ``suspendable``, made suspendable (see the module docstring).

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
    sites = _call_sites(tree.root_node) if suspendable else None
    if sites:
        inserts.extend(sites)
    if not inserts:
        return Instrumented(source, False)
    return _apply(data, inserts, generator=bool(sites))


def instrument(source: str) -> str:
    """The program as ``instrument_program`` makes it, as text."""
    return instrument_program(source).code
