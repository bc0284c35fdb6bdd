"""Instrumenting catch and finally clauses so a suspended step unwinds through them."""

from __future__ import annotations

import pytest

from vvm_worker.runtime import ReservedNameError, check_syntax, instrument


def test_catch_with_a_binding_rethrows_first() -> None:
    out = instrument("try { a(); } catch (err) { b(err); }")
    assert out == "try { a(); } catch (err) { __cpcc_rethrow(err); b(err); }"


def test_catch_without_a_binding_gets_one() -> None:
    out = instrument("try { a(); } catch { b(); }")
    assert out == "try { a(); } catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); b(); }"


def test_catch_with_a_pattern_binds_it_after_the_check() -> None:
    out = instrument("try { a(); } catch ({message, code}) { b(message); }")
    assert "catch (__cpcc_e) { __cpcc_rethrow(__cpcc_e); let {message, code} = __cpcc_e;" in out


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


def test_nested_and_async_clauses_and_unicode_are_all_instrumented() -> None:
    source = (
        "// ünïcödé ✓\nasync function f() { try { await g(); } catch (e) {"
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
