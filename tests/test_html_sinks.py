"""What customers write reaches the pages as text, and the pages need no inline style.

VV names, customer names, vehicle names, storage keys, log lines: whatever comes from the API,
the map socket or a template reaches the page through ``textContent`` or DOM nodes, never
through something that parses a string as HTML. Leaflet's ``bindTooltip``, ``bindPopup``,
``setTooltipContent``, ``setPopupContent`` and ``setContent`` parse a string as HTML (and take
a DOM node as it is): the project's scripts pass them a node made by one of NODE_BUILDERS.

The pages' Content Security Policy (cpcc_site/security.py) allows no inline style: the
templates carry no ``style`` attribute and no ``<style>`` element, and the scripts set no style
string (classes instead; single properties through ``element.style.foo`` are allowed).

These read the project's own files (static/js/, templates/), not the vendored libraries.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from django.http import HttpResponse, HttpResponseNotFound
from django.test import RequestFactory

from cpcc_site.security import HEADER, ContentSecurityPolicyMiddleware, policy

ROOT = Path(__file__).resolve().parent.parent
SCRIPTS = sorted((ROOT / "static" / "js").rglob("*.js"))
TEMPLATES = sorted((ROOT / "templates").rglob("*.html"))

# What parses a string as HTML (or writes it into the document as markup).
SINKS = {
    r"\.innerHTML\b": "innerHTML parses its string as HTML",
    r"\.outerHTML\b": "outerHTML parses its string as HTML",
    r"\binsertAdjacentHTML\b": "insertAdjacentHTML parses its string as HTML",
    r"\bdocument\s*\.\s*write(?:ln)?\b": "document.write writes markup",
    r"\bcreateContextualFragment\b": "createContextualFragment parses its string as HTML",
    r"\bparseFromString\b": "DOMParser.parseFromString parses its string as HTML",
    r"\bsrcdoc\b": "srcdoc is a document written as a string",
    r"(?<![\w$.])\$\s*\(": "jQuery's $() makes HTML out of a string",
    r"\.html\s*\(": "jQuery's .html() parses its string as HTML",
}
# (file, pattern): HTML parsed on purpose, and why that is safe.
ALLOWED_SINKS = {
    # The dashboard's rows as the server renders them (templates/missions/_dashboard_rows.html,
    # every value escaped by Django's templates), parsed in an inert document, then moved over.
    ("static/js/dashboard.js", r"\bparseFromString\b"),
}

# Leaflet's content setters: a string is HTML to them, a DOM node is shown as it is.
LEAFLET_CONTENT = re.compile(
    r"\.(bindTooltip|bindPopup|setTooltipContent|setPopupContent|setContent)\s*\("
)
# The functions of static/js/ that make a DOM node for Leaflet, text set with textContent.
NODE_BUILDERS = ("text", "M.text", "popup")
NODE_CALL = re.compile(r"^(?:" + "|".join(re.escape(b) for b in NODE_BUILDERS) + r")\s*\(")

# Style strings: blocked by the policy (setAttribute) or style as markup.
STYLE_STRINGS = {
    r"setAttribute\s*\(\s*['\"`]style['\"`]": "setAttribute('style', ...) is an inline style",
    r"\.style\s*\.\s*cssText\b": "style.cssText: a style string (use a class)",
    r"\.style\s*=(?!=)": "a string assigned to .style (use a class)",
}
# The same as markup, in a script's string literals.
MARKUP_STYLE = re.compile(r"\sstyle\s*=|<style\b", re.IGNORECASE)


def relative(path: Path) -> str:
    return path.relative_to(ROOT).as_posix()


def without_comments(source: str) -> str:
    """The script with its comments blanked out (line numbers kept), strings left as they are.
    Enough for this project's scripts: no regular expression literal of theirs holds a quote
    or a comment's opening."""
    out: list[str] = []
    i, n = 0, len(source)
    quote = ""
    while i < n:
        c = source[i]
        if quote:
            out.append(c)
            if c == "\\" and i + 1 < n:
                out.append(source[i + 1])
                i += 2
                continue
            if c == quote:
                quote = ""
            i += 1
        elif c in "'\"`":
            quote = c
            out.append(c)
            i += 1
        elif source.startswith("//", i):
            end = source.find("\n", i)
            end = n if end == -1 else end
            out.append(" " * (end - i))
            i = end
        elif source.startswith("/*", i):
            end = source.find("*/", i + 2)
            end = n if end == -1 else end + 2
            out.append(re.sub(r"[^\n]", " ", source[i:end]))
            i = end
        else:
            out.append(c)
            i += 1
    return "".join(out)


def string_literals(code: str) -> list[tuple[int, str]]:
    """Where each string literal of a script (comments blanked) starts, and its text."""
    found = []
    quote = ""
    start = 0
    i = 0
    while i < len(code):
        c = code[i]
        if quote:
            if c == "\\":
                i += 2
                continue
            if c == quote:
                found.append((start, code[start + 1 : i]))
                quote = ""
        elif c in "'\"`":
            quote, start = c, i
        i += 1
    return found


def first_argument(code: str, start: int) -> str:
    """The text of a call's first argument, from just after its opening parenthesis."""
    depth = 0
    quote = ""
    i = start
    while i < len(code):
        c = code[i]
        if quote:
            if c == "\\":
                i += 2
                continue
            if c == quote:
                quote = ""
        elif c in "'\"`":
            quote = c
        elif c in "([{":
            depth += 1
        elif c in ")]}":
            if depth == 0:
                break
            depth -= 1
        elif c == "," and depth == 0:
            break
        i += 1
    return code[start:i].strip()


def line_of(code: str, index: int) -> int:
    return code.count("\n", 0, index) + 1


def test_there_are_scripts_and_templates_to_read() -> None:
    names = {relative(p) for p in SCRIPTS}
    assert {"static/js/map.js", "static/js/vv.js", "static/js/admin/fleet-overview.js"} <= names
    assert any(relative(p) == "templates/base.html" for p in TEMPLATES)


def test_scripts_put_no_string_into_the_page_as_html() -> None:
    problems = []
    for path in SCRIPTS:
        name = relative(path)
        code = without_comments(path.read_text())
        for pattern, why in SINKS.items():
            if (name, pattern) in ALLOWED_SINKS:
                continue
            for found in re.finditer(pattern, code):
                problems.append(f"{name}:{line_of(code, found.start())}: {why}")
        for found in LEAFLET_CONTENT.finditer(code):
            argument = first_argument(code, found.end())
            if not NODE_CALL.match(argument):
                argument = " ".join(argument.split())
                problems.append(
                    f"{name}:{line_of(code, found.start())}: {found.group(1)}({argument})"
                )
    assert not problems, (
        "HTML made of strings (set text with textContent; Leaflet's content setters take a "
        f"string as HTML: pass a DOM node made by {' or '.join(NODE_BUILDERS)}):\n"
        + "\n".join(problems)
    )


def test_the_allowed_sinks_are_still_needed() -> None:
    """An exception that no longer matches anything goes (so that it cannot hide a new one)."""
    for name, pattern in ALLOWED_SINKS:
        code = without_comments((ROOT / name).read_text())
        assert re.search(pattern, code), f"{name} no longer uses {pattern}: drop the exception"


def test_scripts_set_no_style_strings() -> None:
    problems = []
    for path in SCRIPTS:
        code = without_comments(path.read_text())
        for pattern, why in STYLE_STRINGS.items():
            for found in re.finditer(pattern, code):
                problems.append(f"{relative(path)}:{line_of(code, found.start())}: {why}")
        for start, literal in string_literals(code):
            if MARKUP_STYLE.search(" " + literal):
                problems.append(
                    f"{relative(path)}:{line_of(code, start)}: inline style as markup: {literal!r}"
                )
    assert not problems, "inline styles from scripts:\n" + "\n".join(problems)


def test_templates_have_no_inline_style() -> None:
    attribute = re.compile(r"\sstyle\s*=", re.IGNORECASE)
    element = re.compile(r"<style\b", re.IGNORECASE)
    problems = []
    for path in TEMPLATES:
        for number, line in enumerate(path.read_text().splitlines(), start=1):
            if attribute.search(line):
                problems.append(f"{relative(path)}:{number}: a style attribute: {line.strip()}")
            if element.search(line):
                problems.append(f"{relative(path)}:{number}: a <style> element: {line.strip()}")
    assert not problems, (
        "inline styles (the policy refuses them; use a class in static/css/):\n"
        + "\n".join(problems)
    )


@pytest.mark.parametrize("path", ["/", "/map/", "/vvs/1/", "/admin/fleet/vehicle/overview/"])
def test_pages_allow_styles_from_this_site_only(path: str) -> None:
    directives = dict(d.split(" ", 1) for d in policy(RequestFactory().get(path)).split("; "))
    assert directives["style-src"] == "'self'"
    assert directives["script-src"] == "'self'"


@pytest.mark.parametrize(("debug", "styles"), [(False, "'self'"), (True, "'self' 'unsafe-inline'")])
def test_only_the_error_pages_of_development_style_themselves_inline(
    settings, debug: bool, styles: str
) -> None:
    """Django's technical 404 and 500 pages (DEBUG) carry a <style> element; a production
    error page, like every other page, gets no inline style."""
    settings.DEBUG = debug
    middleware = ContentSecurityPolicyMiddleware(lambda request: HttpResponseNotFound("gone"))
    response = middleware(RequestFactory().get("/vvs/1/"))
    directives = dict(d.split(" ", 1) for d in response[HEADER].split("; "))
    assert directives["style-src"] == styles
    assert directives["script-src"] == "'self'"
    ok = ContentSecurityPolicyMiddleware(lambda request: HttpResponse("fine"))
    assert "style-src 'self';" in ok(RequestFactory().get("/vvs/1/"))[HEADER]
