"""A gunicorn worker on its way out is not killed by a second SIGTERM (cpcc_site/gunicorn_conf.py).

Stopping the whole process group sends each worker SIGTERM twice, once directly and once from
the master; late in the worker's shutdown Python has given SIGTERM its default action back, so
without ``worker_exit`` the second one ended the worker by the signal instead of status 0.
"""

from __future__ import annotations

import subprocess
import sys

SHUTDOWN = """
import os, signal, sys
from cpcc_site import gunicorn_conf

# Where the worker stands late in Python's shutdown: SIGTERM has its default action again.
signal.signal(signal.SIGTERM, signal.SIG_DFL)
{exit_hook}
os.kill(os.getpid(), signal.SIGTERM)  # the master's SIGTERM to its workers
sys.exit(0)
"""


def shutdown_status(exit_hook: str) -> int:
    return subprocess.run(
        [sys.executable, "-c", SHUTDOWN.format(exit_hook=exit_hook)], timeout=60
    ).returncode


def test_a_worker_on_its_way_out_exits_with_status_0_when_sigterm_arrives_again() -> None:
    assert shutdown_status("gunicorn_conf.worker_exit(None, None)") == 0


def test_without_the_exit_hook_the_second_sigterm_ends_the_worker() -> None:
    # The failure worker_exit prevents (gunicorn: "Worker (pid:...) was sent SIGTERM!").
    assert shutdown_status("") == -15
