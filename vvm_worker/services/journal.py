"""A VV's journal: the append-only answers of the VVM-API, which a new context replays, and its limits."""

from __future__ import annotations

import json
import threading
from collections import OrderedDict
from collections.abc import Sequence
from typing import Any, overload

from django.conf import settings
from django.db import transaction

from missions.models import (
    LogEntry,
    VirtualVehicle,
)
from vvm_worker.services.base import VVM
from vvm_worker.services.store import journal_insert, journal_texts

# The last entry this process appended to each VV's journal, once committed (VV id -> (seq,
# text)): the next step of the VV here needs it (its context checks it is the same) and
# reads it from memory. Only committed entries: the journal is append-only, so what is here
# is what the database holds.
_RECENT_VVS = 20_000
_recent: OrderedDict[str, tuple[int, str]] = OrderedDict()
_recent_lock = threading.Lock()


def _remember(vv_id: str, seq: int, text: str) -> None:
    with _recent_lock:
        _recent[vv_id] = (seq, text)
        _recent.move_to_end(vv_id)
        while len(_recent) > _RECENT_VVS:
            _recent.popitem(last=False)


class JournalView(Sequence[str]):
    """A VV's journal as the runtime reads it, each entry as JSON text: a warm context asks
    only for the entries it does not have (and the last one it has, to check it is the same),
    a new one for all. Entries appended in this transaction, and the last one this process
    appended before, come from memory; the others from the database."""

    def __init__(self, vv: VirtualVehicle) -> None:
        self.vv = vv
        key = str(vv.pk)
        with _recent_lock:
            recent = _recent.get(key)
        self._known: dict[int, str] = dict([recent]) if recent is not None else {}
        self._known.update(vv.__dict__.get("_journal_fresh", {}))

    def __len__(self) -> int:
        return self.vv.journal_length

    def _texts(self, start: int, stop: int) -> list[str]:
        return journal_texts(self.vv.pk, start, stop)

    @overload
    def __getitem__(self, index: int) -> str: ...

    @overload
    def __getitem__(self, index: slice) -> list[str]: ...

    def __getitem__(self, index: int | slice) -> str | list[str]:
        if isinstance(index, slice):
            start, stop, step = index.indices(len(self))
            assert step == 1
            if all(seq in self._known for seq in range(start, stop)):
                return [self._known[seq] for seq in range(start, stop)]
            return self._texts(start, stop)
        if index < 0:
            index += len(self)
        if not 0 <= index < len(self):
            raise IndexError(index)
        if index in self._known:
            return self._known[index]
        (text,) = self._texts(index, index + 1)
        return text


def journal_append(vv: VirtualVehicle, entry: dict[str, Any], vvm: VVM) -> None:
    """Add an answer to the VV's journal (the caller saves the VV in the same transaction)."""
    seq = vv.journal_length
    text = journal_insert(vv, seq, entry)
    vv.__dict__.setdefault("_journal_fresh", {})[seq] = text
    transaction.on_commit(lambda: _remember(str(vv.pk), seq, text))
    vv.journal_length += 1
    vv.journal_bytes += len(json.dumps(entry, separators=(",", ":")))
    if entry.get("k") not in ("ret", "err"):
        # It waited for the outside world (a task, a message): its CPU quota starts again.
        vv.call_cpu_s = 0.0
    if vv.journal_length == settings.CPCC_JOURNAL_WARN_ENTRIES:
        LogEntry.objects.create(
            vv=vv,
            at_s=vvm.clock.now_s(),
            level="warning",
            message=f"the journal holds {vv.journal_length:,} answers; a VV stops at "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} answers or "
            f"{settings.CPCC_JOURNAL_MAX_BYTES // 1_000_000} MB (a VV that moves replays it)",
        )


def journal_full(vv: VirtualVehicle) -> str | None:
    if vv.journal_length > settings.CPCC_JOURNAL_MAX_ENTRIES:
        return (
            f"the journal holds {vv.journal_length:,} answers, more than the "
            f"{settings.CPCC_JOURNAL_MAX_ENTRIES:,} allowed (quota: journal)"
        )
    if vv.journal_bytes > settings.CPCC_JOURNAL_MAX_BYTES:
        return (
            f"the journal holds {vv.journal_bytes:,} bytes, more than the "
            f"{settings.CPCC_JOURNAL_MAX_BYTES:,} allowed (quota: journal)"
        )
    return None
