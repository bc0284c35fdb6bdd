"""Log lines an operator can follow: the message, then what it is about as ``key=value``.

The platform's loggers (``cpcc.*``) pass what a line is about as ``extra`` (the VV, the
vehicle, the customer, from and to); the plain formatter would drop it. `FieldsFormatter`
appends those fields to the line, values with spaces or quotes in JSON quotes, so that a line
reads as text and parses as logfmt.
"""

from __future__ import annotations

import json
import logging
from typing import Any

# What every LogRecord carries; anything else on a record came as ``extra``.
_STANDARD = frozenset(vars(logging.makeLogRecord({}))) | {"message", "asctime", "taskName"}


def _value(value: Any) -> str:
    text = str(value)
    if not text or any(c in text for c in ' "=\n\t'):
        return json.dumps(text, ensure_ascii=False)
    return text


class FieldsFormatter(logging.Formatter):
    """The standard line, then the ``extra`` fields of the platform's own records."""

    def formatMessage(self, record: logging.LogRecord) -> str:
        line = super().formatMessage(record)
        if not record.name.startswith("cpcc"):
            return line
        fields = [
            f"{key}={_value(value)}"
            for key, value in vars(record).items()
            if key not in _STANDARD and not key.startswith("_") and value is not None
        ]
        return " ".join([line, *fields]) if fields else line
