"""Faults put into a process started by the fault tests (tests/live.py puts this directory on
its PYTHONPATH, so Python runs this file at start-up), each named by a variable of its
environment:

- ``CPCC_FAULT_CLOCK_S``: the process's clock is off by that many seconds (negative: behind):
  ``time.time``, ``time.time_ns`` and Django's ``timezone.now``, which is what the platform
  and its libraries read the time of day from;
- ``CPCC_FAULT_DUPLICATES``: every Celery message the process sends is sent twice, and a line
  appended to the file that the variable names for each duplicate.
"""

from __future__ import annotations

import os

_skew = os.environ.get("CPCC_FAULT_CLOCK_S")
if _skew:
    import datetime
    import time

    from django.utils import timezone

    _SKEW_S = float(_skew)
    _time, _time_ns, _now = time.time, time.time_ns, timezone.now
    time.time = lambda: _time() + _SKEW_S
    time.time_ns = lambda: _time_ns() + int(_SKEW_S * 1e9)
    timezone.now = lambda: _now() + datetime.timedelta(seconds=_SKEW_S)

_duplicates = os.environ.get("CPCC_FAULT_DUPLICATES")
if _duplicates:
    from typing import Any

    from celery.app import base

    _send_task = base.Celery.send_task

    def _send_twice(self: Any, *args: Any, **kwargs: Any) -> Any:
        _send_task(self, *args, **kwargs)
        with open(_duplicates, "a") as log:
            log.write(f"{args[0] if args else kwargs.get('name')}\n")
        return _send_task(self, *args, **kwargs)

    base.Celery.send_task = _send_twice  # type: ignore[method-assign]
