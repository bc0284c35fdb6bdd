"""Log lines an operator can follow (cpcc_site/logs.py): what each line is about is on it."""

from __future__ import annotations

import logging
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from cpcc_site.logs import FieldsFormatter
from vvm_worker.scenario import load_scenario
from vvm_worker.simulation import Simulation

ROOT = Path(__file__).resolve().parents[2]
FORMAT = "%(levelname)s %(name)s %(message)s"


def _record(name: str, message: str, **extra: object) -> logging.LogRecord:
    record = logging.makeLogRecord({"name": name, "msg": message, "levelname": "INFO"})
    record.__dict__.update(extra)
    return record


def test_a_platform_line_carries_its_fields_quoted_where_needed() -> None:
    line = FieldsFormatter(FORMAT).format(
        _record("cpcc.vvm", "vv migrated", vv="ab12", to="Heli Two", reason='a "b"', gone=None)
    )
    assert line == 'INFO cpcc.vvm vv migrated vv=ab12 to="Heli Two" reason="a \\"b\\""'
    # Libraries' records keep their own format (Django's carry requests and such).
    assert FieldsFormatter(FORMAT).format(_record("django.request", "x", status_code=404)) == (
        "INFO django.request x"
    )


@pytest.mark.django_db
def test_a_migrations_line_names_the_vv_both_vehicles_and_the_customer(caplog) -> None:
    caplog.set_level(logging.INFO, logger="cpcc")
    Simulation(load_scenario(ROOT / "examples" / "scenarios" / "paper-fig3.json")).run()
    formatter = FieldsFormatter(FORMAT)
    lines = [
        formatter.format(r)
        for r in caplog.records
        if "migrated from Heli" in r.getMessage() and " to Heli" in r.getMessage()
    ]
    assert lines, "Figure 3 moves VVs between its RVs"
    pattern = (
        r"^INFO cpcc\.vvm vv 'VV \d' migrated from (Heli \w+) to (Heli \w+) vv=[0-9a-f-]{36} "
        r'customer=customer-[abc] from="\1" to="\2" reason='
    )
    assert all(re.match(pattern, line) for line in lines), lines[0]


def test_the_platforms_lines_show_at_the_default_level() -> None:
    env = {k: v for k, v in os.environ.items() if k != "CPCC_LOG_LEVEL"}
    probe = (
        "import django, logging; django.setup(); "
        "print(logging.getLogger('cpcc.vvm').isEnabledFor(logging.INFO), "
        "logging.getLogger('celery').isEnabledFor(logging.INFO))"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=ROOT,
        env={**env, "DJANGO_SETTINGS_MODULE": "cpcc_site.settings"},
        capture_output=True,
        text=True,
        check=True,
    )
    assert out.stdout.split() == ["True", "False"]


def test_a_workers_lines_keep_their_format_and_fields_once_celery_starts() -> None:
    """Celery's worker would put its own format in place when it starts: the lines after
    it would lose what they are about (and read unlike the lines before)."""
    probe = (
        "import django, logging; django.setup(); "
        "from cpcc_site.celery import app; "
        "app.log.setup(loglevel='WARNING', hostname='rv@here'); "
        "logging.getLogger('cpcc.vvm').info('vv ended', extra={'vv': 'ab12'}); "
        "logging.getLogger('celery').info('a library line')"
    )
    out = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=ROOT,
        env={**os.environ, "DJANGO_SETTINGS_MODULE": "cpcc_site.settings", "CPCC_LOG_LEVEL": ""},
        capture_output=True,
        text=True,
        check=True,
    )
    assert re.fullmatch(r"\S+ \S+ INFO cpcc\.vvm vv ended vv=ab12\n", out.stderr), out.stderr
