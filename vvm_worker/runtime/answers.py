"""The journal entries the host writes when it answers a VV's pending request."""

from __future__ import annotations

from typing import Any

from vvm_worker.runtime.types import PendingRequest


def answer_task(pending: PendingRequest, *, time_ms: int, data: list[Any]) -> dict[str, Any]:
    """The journal entry answering a pending ``execute`` with its readings."""
    return _entry(pending, "done", time_ms, data=data)


def answer_reject(pending: PendingRequest, *, time_ms: int, message: str) -> dict[str, Any]:
    """The journal entry rejecting a pending ``execute`` or a whole ``executeAll`` batch."""
    return _entry(pending, "reject", time_ms, message=message)


def answer_part(
    pending: PendingRequest, *, index: int, time_ms: int, data: list[Any]
) -> dict[str, Any]:
    """The journal entry answering one task of a pending ``executeAll`` batch."""
    return _entry(pending, "part", time_ms, i=index, data=data)


def answer_call(pending: PendingRequest, *, time_ms: int, data: Any) -> dict[str, Any]:
    """The journal entry answering a pending "call" (``VV.message.send``, ``VV.image.*``) with
    its result, which the program gets as the call's value."""
    return _entry(pending, "ret", time_ms, data=data)


# The errors a "call" may end in, as the program sees them (classes of prelude.js).
CALL_ERRORS = ("MessageError", "ImageError")


def answer_call_error(
    pending: PendingRequest, *, time_ms: int, name: str, message: str
) -> dict[str, Any]:
    """The journal entry answering a pending "call" with an error: the call throws ``name``
    (one of ``CALL_ERRORS``) with ``message``. Raises ValueError for another name."""
    if name not in CALL_ERRORS:
        raise ValueError(f"a call answers with one of {', '.join(CALL_ERRORS)}, not {name!r}")
    return _entry(pending, "err", time_ms, name=name, message=message)


def answer_message(
    pending: PendingRequest, *, time_ms: int, message: dict[str, Any] | None
) -> dict[str, Any]:
    """The journal entry answering a pending ``VV.message.receive``: the message
    ``{from, id, value, sentAt}`` (``value`` parsed JSON), or None when the wait timed out."""
    return _entry(pending, "msg", time_ms, data=message)


def _entry(pending: PendingRequest, kind: str, time_ms: int, **fields: Any) -> dict[str, Any]:
    entry: dict[str, Any] = {"q": pending.q, "k": kind, "t": int(time_ms), **fields}
    if pending.fingerprint is not None:
        entry["r"] = pending.fingerprint
    return entry
