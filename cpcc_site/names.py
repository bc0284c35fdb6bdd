"""Names people give things (VVs, API tokens): plain text, shown on pages, in the admin and in
terminals. Pure: no Django, nothing of the apps."""

from __future__ import annotations

import unicodedata

# Characters that reorder how the text around them is shown (bidirectional formatting: the
# embeddings, overrides and isolates, and the invisible direction marks). In a name they make
# one thing look like another on the pages, in the admin and in a terminal.
BIDI_CONTROLS = frozenset(
    "\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069"
)


def plain_name_problem(name: str) -> str | None:
    """What is wrong with a name, or None: a name has no control character (C0 and C1, such
    as a terminal's escape ``\\x1b``, a tab or a line break) and no bidirectional formatting
    character (BIDI_CONTROLS)."""
    for position, char in enumerate(name, start=1):
        if unicodedata.category(char) == "Cc":
            what = "a control character"
        elif char in BIDI_CONTROLS:
            what = "a bidirectional formatting character"
        else:
            continue
        label = unicodedata.name(char, "")
        shown = f"U+{ord(char):04X}" + (f" {label}" if label else "")
        return (
            f"The name has {what} ({shown}) at character {position}: a name is plain text "
            "shown on pages and in terminals; remove it."
        )
    return None
