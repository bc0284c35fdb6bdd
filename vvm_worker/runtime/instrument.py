"""Instrumenting a VV program so that a suspended step unwinds through the program's own code.

A step ends by throwing an internal marker from the pending VVM-API call. As blocking code,
the program never sees that call return, so its own ``catch`` clauses must not swallow the
marker and its ``finally`` clauses must not run. The program is rewritten once when it is
loaded, on its tree-sitter-javascript syntax tree (exact byte positions); nothing the user
wrote is moved, re-joined or re-spaced:

    catch (e) { BODY }    ->  catch (e) { __cpcc_rethrow(e); BODY }
    catch { BODY }        ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); BODY }
    catch (PATTERN) { BODY }   (a destructuring pattern)
        ->  catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); try { throw __cpcc_e; }
            catch (PATTERN) { BODY }}                                   (on one line)
    finally { BODY }      ->  finally { if (!__cpcc_suspended()) { BODY } }

A pattern stays byte for byte as written (its comments, its default values and the scope they
are evaluated in), inside a nested ``try`` that hands it the caught value once the marker check
is done. Insertions never contain a newline, so line numbers in error messages stay the user's;
``Instrumented.user_column`` takes a column back to the user's. The text ``__cpcc`` is reserved
for these hooks: a program may not contain it, nor an identifier that reads as it once its
``\\uXXXX`` and ``\\u{X...}`` escapes are decoded (ReservedNameError, with the place).

A program is also made *suspendable* when it can be (``instrument_program``): compiled as a
generator function, with each waiting VVM-API call (``VV.task.execute``,
``VV.task.executeAll``, ``VV.message.send``, ``VV.message.receive``, ``VV.image.stats``,
``VV.image.fraction``, ``VV.image.crop``, ``VV.image.resize``) in its own body waiting by
``yield*``:

    VV.task.execute(ARGS)     ->  (yield* __cpcc_execute(ARGS))
    VV.image.crop(ARGS)       ->  (yield* __cpcc_crop(ARGS))

and so is each such call in a *helper*, a function declared at the program's top level that is
only ever called (never used as a value, never rebound, no ``arguments``) from the program's
body or another helper, and that is not recursive (directly or through other helpers: a
generator's frames take more stack, so a recursive helper stays a plain function and reaches
the depth the user's program reaches): the helper becomes ``function*`` and its calls
``(yield* f(ARGS))``. Between steps the program then stays suspended at the call (the runtime
and prelude.js resume it there). A call anywhere else, in a callback, in a function used as a
value, in a recursive helper, or written across lines (``VV.task\\n.execute(...)``), still ends
the step the replay way. The rewrite changes nothing a program can observe, which is why it is
only made when ``VV`` is the platform's (the program never binds the name, nor uses ``with``)
and the program does not use ``yield`` (a keyword in a generator). Names are compared decoded,
so ``V\\u0056`` is ``VV`` and ``yi\\u0065ld`` is ``yield``.

An inserted ``(`` that starts an expression statement could join the line before it in a
program without semicolons (``var n = 0`` then ``VV.task.execute(t)`` would call ``0``). Where
the statement is in a statement list (the program, a block, a ``switch`` case) and the
statement before it does not end with ``;`` (nor is it the list's first), a ``;`` goes in
front of the ``(`` (an empty statement changes nothing there). Anywhere else the statement
stands alone as the body of ``if``/``else``, a loop, ``do`` or a label, so the token before
the ``(`` is ``)``, ``else``, ``do`` or ``:``, which an expression cannot continue (and an
empty statement there would change the program).

``unsupported`` finds what a VV program may not use although V8 parses it: ``async``
functions (and ``await``), whose continuations the platform cannot wait for, and ``import()``.
"""

from __future__ import annotations

import re
import sys
from collections.abc import Iterator
from dataclasses import dataclass

import tree_sitter_javascript
from tree_sitter import Language, Node, Parser, Tree

from vvm_worker.runtime.memo import TextMemo

RESERVED_PREFIX = "__cpcc"
_RESERVED = re.compile(r"__cpcc\w*")
# An escape in an identifier: \uXXXX or \u{X...}.
_ESCAPE = re.compile(r"\\u(?:\{([0-9a-fA-F]+)\}|([0-9a-fA-F]{4}))")
_LINE_BREAKS = ("\n", "\r", "\u2028", "\u2029")

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
    # At one offset, inserts go in the order (after, listed): a block's closing brace has
    # ``after`` set so that a call ending there (`f(x)` + `)`) closes first.
    after: bool = False


def _decode_escape(match: re.Match[str]) -> str:
    code = int(match.group(1) or match.group(2), 16)
    return chr(code) if code <= 0x10FFFF else match.group(0)


def js_name(text: bytes | str | None) -> str:
    """An identifier's name as JavaScript reads it: its ``\\uXXXX`` and ``\\u{X...}`` escapes
    decoded (``V\\u0056`` is ``VV``)."""
    if text is None:
        return ""
    name = text.decode("utf-8") if isinstance(text, bytes) else text
    return _ESCAPE.sub(_decode_escape, name) if "\\" in name else name


def _parse(data: bytes) -> Tree:
    return Parser(_LANGUAGE).parse(data)


def _nodes(root: Node) -> Iterator[Node]:
    """Every node under ``root`` (``root`` included), depth first."""
    stack = [root]
    while stack:
        node = stack.pop()
        yield node
        stack.extend(reversed(node.children))


def _place(data: bytes, offset: int) -> tuple[int, int]:
    """The 1-based line and column (in characters) of byte ``offset`` of ``data``."""
    line_start = data.rfind(b"\n", 0, offset) + 1
    line = data.count(b"\n", 0, offset) + 1
    return line, len(data[line_start:offset].decode("utf-8", errors="replace")) + 1


# Every kind of node that is an identifier (a name) in tree-sitter-javascript's tree.
_IDENTIFIERS = frozenset(
    {
        "identifier",
        "property_identifier",
        "private_property_identifier",
        "shorthand_property_identifier",
        "shorthand_property_identifier_pattern",
        "statement_identifier",
    }
)


def _find_reserved(source: str, root: Node) -> None:
    """Raise ReservedNameError at the first reserved name: the text ``__cpcc`` anywhere in the
    program, or an identifier whose escapes decode to it."""
    found: list[tuple[int, str]] = []  # (byte offset, name)
    match = _RESERVED.search(source)
    if match is not None:
        found.append((len(source[: match.start()].encode("utf-8")), match.group(0)))
    for node in _nodes(root):
        if node.type in _IDENTIFIERS and node.text and b"\\" in node.text:
            decoded = _RESERVED.search(js_name(node.text))
            if decoded is not None:
                found.append((node.start_byte, decoded.group(0)))
    if not found:
        return
    offset, name = min(found)
    line, column = _place(source.encode("utf-8"), offset)
    raise ReservedNameError(name, line, column)


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
    # A destructuring pattern: the clause as written, `(PATTERN) {BODY}`, stays where it is, byte
    # for byte (comments, default values and their scope), as the handler of a nested try that
    # throws the caught value again once the marker check is done; nothing here adds a line.
    keyword = next((c for c in clause.children if c.type == "catch"), None)
    if keyword is None:
        return []
    return [
        _Insert(
            keyword.end_byte,
            b" (__cpcc_e) { __cpcc_rethrow(__cpcc_e); try { throw __cpcc_e; } catch",
        ),
        _Insert(body.end_byte, b"}", after=True),
    ]


def _finally_inserts(clause: Node) -> list[_Insert]:
    body = clause.child_by_field_name("body")
    if body is None:
        body = next((c for c in clause.children if c.type == "statement_block"), None)
    if body is None:
        return []
    return [
        _Insert(body.start_byte + 1, b" if (!__cpcc_suspended()) {"),
        _Insert(body.end_byte - 1, b"} ", after=True),
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
# The waiting calls, ``VV.NAMESPACE.NAME``, and the hooks of prelude.js that replace them.
_SUSPENDING = {
    ("task", "execute"): b"__cpcc_execute",
    ("task", "executeAll"): b"__cpcc_executeAll",
    ("message", "send"): b"__cpcc_send",
    ("message", "receive"): b"__cpcc_receive",
    ("image", "stats"): b"__cpcc_stats",
    ("image", "fraction"): b"__cpcc_fraction",
    ("image", "crop"): b"__cpcc_crop",
    ("image", "resize"): b"__cpcc_resize",
}
# The names that bind or refer to a variable (property names are not variables).
_NAMES = frozenset(
    {
        "identifier",
        "shorthand_property_identifier",
        "shorthand_property_identifier_pattern",
        "statement_identifier",
    }
)
# Where statements follow one another: an empty statement can go in front of any of them.
_STATEMENT_LISTS = frozenset(
    {"program", "statement_block", "switch_case", "switch_default", "class_static_block"}
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


def _member(node: Node | None, name: str) -> Node | None:
    """The object of ``node`` when it is ``OBJECT.name`` (no ``?.``, escapes decoded)."""
    if node is None or node.type != "member_expression":
        return None
    if any(c.type == "optional_chain" for c in node.children):
        return None
    prop = node.child_by_field_name("property")
    if prop is None or prop.type != "property_identifier" or js_name(prop.text) != name:
        return None
    return node.child_by_field_name("object")


def _waiting_hook(callee: Node) -> bytes | None:
    """The hook replacing ``callee`` when it is one of the waiting calls (``VV.task.execute``,
    ``VV.message.send``, ``VV.image.crop``...) written on one line (replacing text across
    lines would move the lines after it)."""
    for (namespace, name), hook in _SUSPENDING.items():
        vv = _member(_member(callee, name), namespace)
        if vv is not None and vv.type == "identifier" and js_name(vv.text) == "VV":
            text = (callee.text or b"").decode("utf-8")
            return None if any(b in text for b in _LINE_BREAKS) else hook
    return None


def _yield_text(callee: Node, hook: bytes | None) -> bytes:
    """What replaces ``callee``: ``(yield* HOOK`` for a waiting call, ``(yield* f`` for a
    helper's. V8 places a call ``VV.image.crop(...)`` at its name, ``crop``: the hook's name
    is spaced to start at the same column, so that the place V8 reports in the hook's name
    (``Instrumented.user_column``) is the place it reports in the user's text."""
    prop = callee.child_by_field_name("property") if hook is not None else None
    if hook is None or prop is None:
        return b"(yield* " + (callee.text or b"")
    before = (callee.text or b"")[: prop.start_byte - callee.start_byte].decode("utf-8")
    return b"(yield*" + b" " * max(1, len(before) - len("(yield*")) + hook


def _last_token(node: Node) -> Node:
    """The last token of ``node`` that is not a comment."""
    while True:
        last = next((c for c in reversed(node.children) if c.type != "comment"), None)
        if last is None:
            return node
        node = last


def _may_join(call: Node) -> bool:
    """Whether a ``(`` put in front of ``call`` could join the statement before it: ``call``
    starts an expression statement in a statement list, after a statement not ended by ``;``
    (see the module docstring)."""
    node = call
    while node.parent is not None and node.parent.start_byte == call.start_byte:
        node = node.parent
        if node.type == "expression_statement":
            if node.parent is None or node.parent.type not in _STATEMENT_LISTS:
                return False
            before = node.prev_sibling
            while before is not None and before.type == "comment":
                before = before.prev_sibling
            if before is None:
                return False  # the first statement of the program
            last = _last_token(before)
            return not (last.type in (";", "{", ":") and last.end_byte > last.start_byte)
    return False


def _recursive(edges: dict[str, set[str]]) -> set[str]:
    """The nodes of the directed graph ``edges`` that are on a cycle (Tarjan, iteratively)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    on_stack: set[str] = set()
    stack: list[str] = []
    cyclic: set[str] = set()
    for root in edges:
        if root in index:
            continue
        work: list[tuple[str, Iterator[str]]] = [(root, iter(edges.get(root, ())))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, successors = work[-1]
            advanced = False
            for nxt in successors:
                if nxt not in index:
                    index[nxt] = low[nxt] = len(index)
                    stack.append(nxt)
                    on_stack.add(nxt)
                    work.append((nxt, iter(edges.get(nxt, ()))))
                    advanced = True
                    break
                if nxt in on_stack:
                    low[node] = min(low[node], index[nxt])
            if advanced:
                continue
            work.pop()
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[node])
            if low[node] == index[node]:
                component: list[str] = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1 or node in edges.get(node, ()):
                    cyclic.update(component)
    return cyclic


_TOP = ""  # where a call is: in the program's own body


def _call_sites(root: Node) -> list[_Insert] | None:
    """The inserts turning the program's waiting calls into ``yield*``, or None when the
    program cannot be made a generator unnoticed (see the module docstring).

    The waiting calls (``_SUSPENDING``) in the program's own body become ``yield*`` calls of the
    hooks. So do those in the body of a *helper*, a function declared at the top level that is
    only ever called (never used as a value nor given another binding, and not using
    ``arguments``) and is not recursive, which then becomes a generator, and so do the calls of
    such a helper where they are in the program's body or in another one's.
    """
    if root.has_error:
        return None
    helpers: dict[str, Node] = {}
    unusable: set[str] = set()
    for child in root.children:
        declared = child.child_by_field_name("name")
        if (
            child.type == "function_declaration"
            and not any(c.type == "async" for c in child.children)
            and declared is not None
            and declared.text
        ):
            name = js_name(declared.text)
            if name in helpers:
                unusable.add(name)  # declared twice
            helpers[name] = child
    by_node = {node.id: name for name, node in helpers.items()}
    # Where each waiting call and each call of a helper is: _TOP, the name of the helper in
    # whose own body it is, or None (in a function or class of its own, or in parameters).
    waits: list[tuple[Node, bytes, str | None]] = []  # (call, hook, where)
    calls: list[tuple[Node, str, str | None]] = []  # (call, helper called, where)
    # (node, where it is, the helper whose declaration holds it at any depth)
    stack: list[tuple[Node, str | None, str | None]] = [(root, _TOP, None)]
    while stack:
        node, where, within = stack.pop()
        kind = node.type
        if kind in _NAMES:
            text = js_name(node.text)
            parent = node.parent
            if text == "yield":
                return None
            if text == "VV" and (
                kind != "identifier"
                or parent is None
                or parent.type != "member_expression"
                or parent.child_by_field_name("object") != node
            ):
                return None
            if text == "arguments" and within is not None:
                unusable.add(within)  # an arrow function inside sees the helper's arguments
            if text in helpers and node != helpers[text].child_by_field_name("name"):
                if parent is not None and _plain_call(parent) == node:
                    calls.append((parent, text, where))
                else:
                    unusable.add(text)
        elif kind == "with_statement":
            return None
        callee = _plain_call(node)
        hook = _waiting_hook(callee) if callee is not None and where is not None else None
        if hook is not None:
            waits.append((node, hook, where))
        helper = by_node.get(node.id) if where == _TOP else None
        if helper is not None:
            body = node.child_by_field_name("body")
            for child in node.children:
                stack.append((child, helper if child == body else None, helper))
        else:
            below = None if kind in _NESTED else where
            stack.extend((child, below, within) for child in node.children)
    # A recursive helper stays a plain function: generator frames cost more stack.
    edges: dict[str, set[str]] = {}
    for _, callee_name, where in calls:
        if where:
            edges.setdefault(where, set()).add(callee_name)
    unusable |= _recursive(edges)
    # The helpers that become generators: those that wait (in their own body, or by calling
    # one that does) and are called only where a `yield` can be.
    chosen = set(helpers) - unusable
    while True:
        waiting: set[str] = set()
        grown = True
        while grown:
            grown = False
            for name in chosen - waiting:
                if any(w == name for _, _, w in waits) or any(
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
    # (call, the hook it calls instead, or None for a helper's call)
    sites: list[tuple[Node, bytes | None]] = [
        (call, hook) for call, hook, w in waits if w == _TOP or w in chosen
    ]
    sites += [(call, None) for call, name, _ in calls if name in chosen]
    for call, target in sites:
        callee = _plain_call(call)
        assert callee is not None and callee.text is not None
        if _may_join(call):
            inserts.append(_Insert(callee.start_byte, b";"))
        inserts.append(
            _Insert(
                callee.start_byte,
                _yield_text(callee, target),
                replace_to=callee.end_byte,
            )
        )
        inserts.append(_Insert(call.end_byte, b")"))
    return inserts


def _apply(data: bytes, inserts: list[_Insert], *, generator: bool) -> Instrumented:
    """``data`` with ``inserts`` made, and where they moved the columns."""
    out = data
    # Apply from the end so earlier offsets stay valid; at one offset, the insert that must end
    # up first (see _Insert.after, then the one listed first) is applied last.
    ordered = sorted(enumerate(inserts), key=lambda pair: (pair[1].offset, pair[1].after, pair[0]))
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
        line, column = _place(out, start_out)
        text = len(ins.text.decode("utf-8"))
        replaced = len(data[ins.offset : end].decode("utf-8"))
        shifts.setdefault(line, []).append((column, column + text, text - replaced, replaced))
    return Instrumented(
        code, generator, tuple((line, tuple(moves)) for line, moves in sorted(shifts.items()))
    )


def _instrument_program(source: str, suspendable: bool) -> Instrumented:
    """``instrument_program``, not remembered."""
    data = source.encode("utf-8")
    root = _parse(data).root_node
    _find_reserved(source, root)
    inserts: list[_Insert] = []
    for clause in _nodes(root):
        if clause.type not in ("catch_clause", "finally_clause") or clause.has_error:
            continue
        if clause.type == "catch_clause":
            inserts.extend(_catch_inserts(clause))
        else:
            inserts.extend(_finally_inserts(clause))
    sites = _call_sites(root) if suspendable else None
    if sites:
        inserts.extend(sites)
    if not inserts:
        return Instrumented(source, False)
    return _apply(data, inserts, generator=bool(sites))


def _instrumented_bytes(instrumented: Instrumented) -> int:
    moves = sum(len(inserts) for _, inserts in instrumented.shifts)
    return sys.getsizeof(instrumented.code) + 128 * (len(instrumented.shifts) + moves)


# A worker resumes the VVs aboard from their programs at every step: this keeps the
# instrumented programs of a few hundred VVs of ordinary size (tens of kilobytes).
INSTRUMENTED_CACHE_BYTES = 32 * 1024 * 1024
_INSTRUMENTED: TextMemo[Instrumented] = TextMemo(
    _instrument_program, max_bytes=INSTRUMENTED_CACHE_BYTES, size_of=_instrumented_bytes
)


def instrument_program(source: str, *, suspendable: bool = True) -> Instrumented:
    """The program with its catch and finally clauses instrumented and, when it can be and
    ``suspendable``, made suspendable (see the module docstring).

    Raises ReservedNameError when the program uses a reserved identifier. Syntax is checked by
    V8 before this is called; a clause tree-sitter cannot parse is left as it is. Remembered
    by the program's digest (``memo.TextMemo``, ``INSTRUMENTED_CACHE_BYTES``).
    """
    return _INSTRUMENTED(source, suspendable)


def instrument(source: str) -> str:
    """The program as ``instrument_program`` makes it, as text."""
    return instrument_program(source).code


# What V8 parses in a script but a VV program cannot use, by the kind of node that has it.
_ASYNC_REASON = (
    "VV.task.execute blocks until its task is done, so a VV program needs no async or await"
)
_ASYNC_KINDS = {
    "function_declaration": "async functions",
    "function_expression": "async functions",
    "arrow_function": "async arrow functions",
    "method_definition": "async methods",
    "generator_function_declaration": "async generators",
    "generator_function": "async generators",
}


def unsupported(source: str) -> tuple[str, int, int] | None:
    """What the program uses that a VV program may not although V8 parses it, as (message,
    1-based line, column) of the first such thing: an ``async`` function, arrow function,
    method or generator, or ``import(...)``. None when there is nothing.

    An ``await`` V8 accepts in a script is in an async function (a script has no top-level
    await), which comes first; elsewhere ``await`` is a name (``await(x)`` calls a function
    of that name, which tree-sitter may take for an await expression).
    """
    data = source.encode("utf-8")
    for node in _nodes(_parse(data).root_node):
        kind = node.type
        what: str | None = None
        if kind in _ASYNC_KINDS and any(c.type == "async" for c in node.children):
            what = f"{_ASYNC_KINDS[kind]} are not supported: {_ASYNC_REASON}"
            if kind == "method_definition" and any(c.type == "*" for c in node.children):
                what = f"async generators are not supported: {_ASYNC_REASON}"
        elif kind == "call_expression":
            function = node.child_by_field_name("function")
            if function is not None and function.type == "import":
                what = (
                    "import() is not supported: a VV program is one script and loads no "
                    "modules; it reaches the platform through VV"
                )
        if what is not None:
            line, column = _place(data, node.start_byte)
            return what, line, column
    return None
