"""Instrumenting catch and finally clauses so a suspended step unwinds through them, making a
program suspendable, and what a VV program may not use (``unsupported``)."""

from __future__ import annotations

import pytest

from vvm_worker.runtime import ReservedNameError, check_syntax, instrument
from vvm_worker.runtime.instrument import instrument_program, js_name, unsupported


def parses_as_generator(code: str) -> bool:
    """Whether V8 parses ``code`` as the body of a generator function (as engine.py compiles a
    suspendable program)."""
    return check_syntax("(function* () {" + code + "\n});") is None


def test_catch_with_a_binding_rethrows_first() -> None:
    out = instrument("try { a(); } catch (err) { b(err); }")
    assert out == "try { a(); } catch (err) { __cpcc_rethrow(err); b(err); }"


def test_catch_without_a_binding_gets_one() -> None:
    out = instrument("try { a(); } catch { b(); }")
    assert out == "try { a(); } catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); b(); }"


def test_catch_with_a_pattern_gets_the_value_in_a_nested_try_after_the_check() -> None:
    out = instrument("try { a(); } catch ({message, code}) { b(message); }")
    assert out == (
        "try { a(); } catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); try { throw __cpcc_e; }"
        " catch ({message, code}) { b(message); }}"
    )


def test_a_catch_pattern_stays_byte_for_byte_as_written() -> None:
    clause = (
        "({message, // the text\n  code = 'two  spaces',\n  /* more */ stack}) {\n  b(code);\n}"
    )
    source = f"try {{ a(); }} catch {clause}\nc();\n"
    out = instrument(source)
    assert out == (
        "try { a(); } catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); try { throw __cpcc_e; }"
        f" catch {clause}}}\nc();\n"
    )
    assert out.count("\n") == source.count("\n")
    assert check_syntax(out) is None


def test_a_column_after_a_catch_pattern_insert_is_the_users() -> None:
    source = "try { a(); } catch ({message}) { b(message); }"
    done = instrument_program(source)
    assert done.user_column(1, done.code.index("b(message)") + 1) == source.index("b(") + 1
    assert done.user_column(1, done.code.index("{message}") + 1) == source.index("{m") + 1
    assert done.user_column(1, done.code.index("try { throw") + 1) == source.index("catch") + 6


def test_finally_is_skipped_while_suspended() -> None:
    out = instrument("try { a(); } finally { b(); }")
    assert out == "try { a(); } finally { if (!__cpcc_suspended()) { b(); } } "[:-1]


def test_empty_finally_stays_valid() -> None:
    out = instrument("try { a(); } catch (e) {} finally {}")
    assert check_syntax(out) is None


def test_line_numbers_do_not_move() -> None:
    source = "try {\n  a();\n} catch (e) {\n  b();\n} finally {\n  c();\n}\nd();\n"
    out = instrument(source)
    assert out.count("\n") == source.count("\n")
    assert out.splitlines()[7] == "d();"


def test_nested_clauses_and_unicode_are_all_instrumented() -> None:
    source = (
        "// ünïcödé ✓\nfunction f() { try { g(); } catch (e) {"
        " try { h(); } catch (e2) { } } }\nvar s = '✓'; try { x } catch (e3) { }"
    )
    out = instrument(source)
    assert out.count("__cpcc_rethrow(") == 3
    assert check_syntax(out) is None
    assert "'✓'" in out


def test_a_program_without_clauses_is_unchanged() -> None:
    source = "var a = 1; // catch (e) in a comment\nvar s = 'finally { }';"
    assert instrument(source) == source


def test_reserved_names_are_refused() -> None:
    with pytest.raises(
        ReservedNameError, match=r"line 2, column 5: the name '__cpcc_x' is reserved"
    ):
        instrument("var a;\nvar __cpcc_x = 1;")


@pytest.mark.parametrize(
    ("source", "name", "line", "column"),
    [
        ("var a;\nvar \\u005f_cpcc_x = 1;", "__cpcc_x", 2, 5),
        ("var a;\n  \\u{5f}\\u{5F}cpcc = 1;", "__cpcc", 2, 3),
        ("var ü = 1, o = {};\no.\\u005f_cpcc_e = ü;", "__cpcc_e", 2, 3),
        ("try {} catch ({\\u005f_cpcc_e}) {}", "__cpcc_e", 1, 16),
    ],
)
def test_reserved_names_written_with_escapes_are_refused(
    source: str, name: str, line: int, column: int
) -> None:
    with pytest.raises(ReservedNameError) as raised:
        instrument(source)
    assert f"line {line}, column {column}: the name {name!r} is reserved" in str(raised.value)
    assert (raised.value.line, raised.value.column) == (line, column)


def test_names_are_decoded_as_javascript_reads_them() -> None:
    assert js_name(b"V\\u0056") == "VV"
    assert js_name("yi\\u{65}ld") == "yield"
    assert js_name("\\u{1F600}x") == "\U0001f600x"
    assert js_name("plain") == "plain"


@pytest.mark.parametrize(
    ("source", "generator"),
    [
        ("V\\u0056.task.execute(t);", True),
        ("VV.t\\u0061sk.ex\\u{65}cuteAll([t]);", True),
        ("var V\\u0056 = {task: {execute: function () {}}}; VV.task.execute(t);", False),
        ("var o = {V\\u0056}; VV.task.execute(t);", False),
        ("var yi\\u0065ld = 1; VV.task.execute(t);", False),
        # Written across lines: replacing the callee would move the lines after it.
        ("VV.task\n  .execute(t);", False),
    ],
)
def test_escaped_names_are_the_names_they_spell(source: str, generator: bool) -> None:
    assert check_syntax(source) is None
    done = instrument_program(source)
    assert done.generator is generator
    assert done.code.count("\n") == source.count("\n")
    if generator:
        assert parses_as_generator(done.code)


def test_a_helper_used_under_an_escaped_name_stays_a_function() -> None:
    source = "function f() { VV.task.execute(t); }\nvar g = \\u0066; g(); f();"
    done = instrument_program(source)
    assert "function* f" not in done.code
    assert "(yield* f())" not in done.code
    called = "function f() { VV.task.execute(t); }\n\\u0066();"
    assert "(yield* \\u0066())" in instrument_program(called).code


@pytest.mark.parametrize(
    "source",
    [
        "function f(k) { VV.task.execute(t); if (k) f(k - 1); } f(2);",
        "function f(k) { VV.task.execute(t); if (k) g(k - 1); }\n"
        "function g(k) { return f(k); }\nf(2);",
        "function f(k) { VV.task.execute(t); if (k) g(k - 1); }\n"
        "function g(k) { return h(k); }\nfunction h(k) { return f(k); }\nf(2);",
    ],
)
def test_a_recursive_helper_is_not_made_a_generator(source: str) -> None:
    done = instrument_program(source)
    assert "function*" not in done.code
    assert "yield" not in done.code


def test_a_helper_calling_a_recursive_one_is_not_made_a_generator_for_it() -> None:
    source = (
        "function down(k) { return k ? down(k - 1) : VV.task.execute(t); }\n"
        "function survey() { VV.task.execute(t); return down(3); }\n"
        "survey(); VV.task.execute(t);"
    )
    done = instrument_program(source)
    assert "function* survey" in done.code and "function down" in done.code
    assert "(yield* survey())" in done.code and "(yield* down" not in done.code
    assert "return down(3)" in done.code
    assert parses_as_generator(done.code)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        # After a statement not ended by `;`, in a statement list: an empty statement first.
        ("var n = 0\nVV.task.execute(t)", "var n = 0\n;(yield* __cpcc_execute(t))"),
        (
            "f = function () {}\nVV.task.execute(t).x",
            "f = function () {}\n;(yield* __cpcc_execute(t)).x",
        ),
        ("x\n// c\nVV.task.execute(t), 1", "x\n// c\n;(yield* __cpcc_execute(t)), 1"),
        ("'use strict'\nVV.task.execute(t)", "'use strict'\n;(yield* __cpcc_execute(t))"),
        ("{ a\n  VV.task.execute(t) }", "{ a\n  ;(yield* __cpcc_execute(t)) }"),
        (
            "switch (a) { case 1: b\n VV.task.execute(t) }",
            "switch (a) { case 1: b\n ;(yield* __cpcc_execute(t)) }",
        ),
        (
            "function f() { a\n VV.task.execute(t) }\nvar x = 1\nf()",
            "function* f() { a\n ;(yield* __cpcc_execute(t)) }\nvar x = 1\n;(yield* f())",
        ),
        # After `;`, `{`, `:` or at the program's start nothing can join: nothing is added.
        ("VV.task.execute(t)", "(yield* __cpcc_execute(t))"),
        ("a;\nVV.task.execute(t)", "a;\n(yield* __cpcc_execute(t))"),
        ("{VV.task.execute(t)}", "{(yield* __cpcc_execute(t))}"),
        (
            "switch (a) { case 1:\n VV.task.execute(t) }",
            "switch (a) { case 1:\n (yield* __cpcc_execute(t)) }",
        ),
        # Not at a statement's start: the token before is an operator or punctuation.
        ("var d = 1\nvar e = VV.task.execute(t)", "var d = 1\nvar e = (yield* __cpcc_execute(t))"),
        ("a\n(VV.task.execute(t))", "a\n((yield* __cpcc_execute(t)))"),
        # A statement standing alone: after `)`, `else`, `do` or `:` a `(` cannot join (and an
        # empty statement there would change the program).
        (
            "if (a) VV.task.execute(t)\nelse VV.task.execute(t)",
            "if (a) (yield* __cpcc_execute(t))\nelse (yield* __cpcc_execute(t))",
        ),
        ("for (;;) VV.task.execute(t)", "for (;;) (yield* __cpcc_execute(t))"),
        ("for (k in o) VV.task.execute(t)", "for (k in o) (yield* __cpcc_execute(t))"),
        ("while (a) VV.task.execute(t)", "while (a) (yield* __cpcc_execute(t))"),
        ("do VV.task.execute(t)\nwhile (a)", "do (yield* __cpcc_execute(t))\nwhile (a)"),
        ("a\nhere: VV.task.execute(t)", "a\nhere: (yield* __cpcc_execute(t))"),
    ],
)
def test_an_inserted_parenthesis_never_joins_the_statement_before(
    source: str, expected: str
) -> None:
    assert check_syntax(source) is None
    done = instrument_program(source)
    assert done.code == expected
    assert parses_as_generator(done.code)


def test_a_call_ending_where_a_finally_block_ends_closes_first() -> None:
    out = instrument("try {} finally {VV.task.execute(t)}")
    assert out == "try {} finally { if (!__cpcc_suspended()) {(yield* __cpcc_execute(t))} }"
    assert parses_as_generator(out)


def test_a_column_after_an_inserted_semicolon_is_the_users() -> None:
    source = "a\nVV.task.execute(t, function () { y(); });"
    done = instrument_program(source)
    assert done.code.startswith("a\n;(yield* __cpcc_execute(t, function")
    line = done.code.split("\n")[1]
    assert done.user_column(2, line.index("y()") + 1) == source.split("\n")[1].index("y()") + 1
    assert done.user_column(2, line.index("__cpcc_execute") + 1) == 9  # at "execute"
    assert done.user_column(2, 1) == 1


ASYNC = (
    "are not supported: VV.task.execute blocks until its task is done, so a VV program needs"
    " no async or await"
)


@pytest.mark.parametrize(
    ("source", "expected"),
    [
        ("async function f() {}", (f"async functions {ASYNC}", 1, 1)),
        ("var a;\n  var f = async function () {};", (f"async functions {ASYNC}", 2, 11)),
        ("var f = async x => x;", (f"async arrow functions {ASYNC}", 1, 9)),
        ("[1].map(async (x) => {\n  await x;\n});", (f"async arrow functions {ASYNC}", 1, 9)),
        ("var o = {async m() {}};", (f"async methods {ASYNC}", 1, 10)),
        ("class A {\n  async m() {}\n}", (f"async methods {ASYNC}", 2, 3)),
        ("async function* g() {}", (f"async generators {ASYNC}", 1, 1)),
        ("var o = {async *g() {}};", (f"async generators {ASYNC}", 1, 10)),
        ("// ✓ ü\nvar ü = 1; import('x');", ("import() is not supported", 2, 12)),
        # What only looks like them.
        ("var async = function (x) { return x; }; async(1);", None),
        ("var async = 1;\nasync\nfunction f() {}", None),
        ("var await = function () {}; await(2);", None),
        ("var o = {async: 1, await: 2}; o.async;", None),
        ("function* g() { yield 1; } var s = 'async function';", None),
    ],
)
def test_async_await_and_import_are_found_with_their_place(
    source: str, expected: tuple[str, int, int] | None
) -> None:
    found = unsupported(source)
    if expected is None:
        assert found is None
        assert check_syntax(source) is None
    else:
        assert found is not None
        message, line, column = expected
        assert found[0].startswith(message)
        assert found[1:] == (line, column)
        problem = check_syntax(source)
        assert problem is not None
        assert (problem.message, problem.line, problem.column) == found
