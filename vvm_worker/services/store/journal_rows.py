"""A VV's journal in the store: an entry inserted with its text as the database keeps it (on
PostgreSQL written here as jsonb writes it, so the INSERT need not be waited for), and the
entries' texts read back in order."""

from __future__ import annotations

import decimal
import functools
import json
import math
import uuid
from typing import Any

from django.db import connection
from django.db.models import TextField
from django.db.models.functions import Cast

from cpcc_site.prepared import PreparedRead, deferred
from missions.models import JournalEntry, VirtualVehicle


def journal_insert(vv: VirtualVehicle, seq: int, entry: dict[str, Any]) -> str:
    """Insert the VV's journal entry ``seq``; its text exactly as the database gives it back,
    so that a warm context and a replay see the same objects. SQLite keeps the JSON text Django wrote (keys
    in the order they were made); PostgreSQL's jsonb orders keys and writes numbers its own
    way: the text is written that way here and sent as it is, the INSERT not waited for (in a
    ``pipelined`` unit of work). An entry that text cannot say for sure (a string with a lone
    surrogate, a key that is not a string) is read back from the INSERT itself."""
    if connection.vendor == "sqlite":
        JournalEntry.objects.create(vv=vv, seq=seq, entry=entry)
        return json.dumps(entry)
    meta = JournalEntry._meta
    vv_id = meta.get_field("vv").get_db_prep_value(vv.pk, connection)
    try:
        text = jsonb_text(entry)
    except (TypeError, ValueError):
        with connection.cursor() as cursor:
            cursor.execute(
                _insert_sql(connection.vendor, read_back=True),
                [vv_id, seq, meta.get_field("entry").get_db_prep_save(entry, connection)],
            )
            (text,) = cursor.fetchone()
        return str(text)
    with deferred(), connection.cursor() as cursor:  # (a refusal fails the unit of work)
        cursor.execute(_insert_sql(connection.vendor, read_back=False), [vv_id, seq, text])
    return text


@functools.cache
def _insert_sql(vendor: str, *, read_back: bool) -> str:
    """``journal_insert``'s statements, written once per database: with the entry as Django
    sends it and read back, or as jsonb text."""
    meta, quote = JournalEntry._meta, connection.ops.quote_name
    vv, seq, entry = (quote(meta.get_field(name).column) for name in ("vv", "seq", "entry"))
    insert = f"INSERT INTO {quote(meta.db_table)} ({vv}, {seq}, {entry}) "
    if read_back:
        return f"{insert}VALUES (%s, %s, %s) RETURNING CAST({entry} AS text)"
    return f"{insert}VALUES (%s, %s, CAST(%s AS jsonb))"


_TEXTS = PreparedRead(
    lambda vv_id, start, stop: (
        JournalEntry.objects.filter(vv_id=vv_id, seq__gte=start, seq__lt=stop)
        .annotate(text=Cast("entry", output_field=TextField()))
        .order_by("seq")
        .values_list("text")
    ),
    samples=[("vv", uuid.UUID(int=0)), ("seq", 2_054_321_001), ("seq", 2_054_321_002)],
)


def journal_texts(vv_id: uuid.UUID, start: int, stop: int) -> list[str]:
    """The VV's entries from ``start`` to before ``stop``, as JSON text in order: what a
    context that catches up (or a new one) reads."""
    return [text for (text,) in _TEXTS.rows(vv_id, start, stop)]


# --- jsonb's text -----------------------------------------------------------------------------

# How PostgreSQL writes a string in jsonb's text (escape_json): these escaped by name, every
# other control character as \u00xx, everything else as it is.
_JSONB_ESCAPES = {
    **{code: f"\\u{code:04x}" for code in range(0x20)},
    ord("\b"): "\\b",
    ord("\f"): "\\f",
    ord("\n"): "\\n",
    ord("\r"): "\\r",
    ord("\t"): "\\t",
    ord('"'): '\\"',
    ord("\\"): "\\\\",
}


def _jsonb_string(text: str) -> str:
    if "\x00" in text:
        raise ValueError("jsonb holds no NUL character")
    try:
        text.encode("utf-8")
    except UnicodeEncodeError:
        raise ValueError("a lone surrogate: jsonb would refuse or join it") from None
    return f'"{text.translate(_JSONB_ESCAPES)}"'


def _jsonb_number(number: float) -> str:
    """A float as jsonb writes what ``json.dumps`` wrote of it: numeric's plain notation,
    as many decimals as written (1e-07 -> 0.0000001, 1.5e+20 -> 150000000000000000000), and
    no negative zero."""
    if not math.isfinite(number):
        raise ValueError(f"{number!r} is not a JSON number")
    written = float.__repr__(number)
    if "e" in written:
        written = format(decimal.Decimal(written), "f")
    return written.removeprefix("-") if number == 0 else written


def _jsonb_key(key: str) -> tuple[int, bytes]:
    encoded = key.encode("utf-8")
    return len(encoded), encoded


def jsonb_text(value: Any) -> str:
    """``value`` (JSON types: dict with string keys, list, str, int, float, bool, None) as
    PostgreSQL writes it once stored as jsonb: keys shortest first, then by their UTF-8
    bytes; ``", "`` and ``": "`` between items; numbers and strings as above. Raises
    TypeError for anything else, ValueError for a value jsonb would not store as it is."""
    if value is None:
        return "null"
    if value is True:
        return "true"
    if value is False:
        return "false"
    if isinstance(value, str):
        return _jsonb_string(value)
    if isinstance(value, int):
        return int.__repr__(value)
    if isinstance(value, float):
        return _jsonb_number(value)
    if isinstance(value, list | tuple):
        return f"[{', '.join(jsonb_text(item) for item in value)}]"
    if isinstance(value, dict):
        if not all(isinstance(key, str) for key in value):
            raise TypeError("a JSON object's keys are strings")
        items = sorted(value.items(), key=lambda item: _jsonb_key(item[0]))
        return f"{{{', '.join(f'{_jsonb_string(k)}: {jsonb_text(v)}' for k, v in items)}}}"
    raise TypeError(f"not a JSON value: {type(value).__name__}")
