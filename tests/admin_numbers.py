"""Reading the numbers a person reads on an admin page (tests/fleet/test_admin.py and
tests/missions/test_admin.py)."""

from __future__ import annotations

import re

# A float printed with all its digits (6831.406656359808): what a person should never have to
# read.
RAW_FLOAT = re.compile(r"\d\.\d{7,}")
_SHOWN = re.compile(r'<(td|th)(?:\s[^>]*)?>(.*?)</\1>|<div class="readonly">(.*?)</div>', re.S)


def cells(page: str) -> str:
    """The text a person reads in an admin list or change page: its table cells and read-only
    fields (not the scripts and map data that carry coordinates for the map)."""
    return "\n".join(cell or field for _, cell, field in _SHOWN.findall(page))
