"""A web worker warms up before its first request: views imported, V8 ready, the broker's
connection made; a broker that does not answer leaves the web working."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests.cpcc_site.test_security import ROOT

CODE = (
    "import json, logging, sys; logging.basicConfig(level=logging.WARNING); "
    "from cpcc_site.wsgi import warm_up; "
    "before = 'missions.api.views' in sys.modules; warm_up(); "
    "print(json.dumps([before, 'missions.api.views' in sys.modules, "
    "'vvm_worker.runtime.syntax' in sys.modules]))"
)


def test_warm_up_imports_the_views_and_survives_a_broker_that_does_not_answer(
    tmp_path: Path,
) -> None:
    out = subprocess.run(
        [sys.executable, "-c", CODE],
        cwd=ROOT,
        env={
            **os.environ,
            "CPCC_VAR_DIR": str(tmp_path),
            "CPCC_ISOLATE_POOL": "0",
            "REDIS_URL": "redis://127.0.0.1:9/0",  # nothing listens there
        },
        capture_output=True,
        text=True,
        timeout=60,
        check=True,
    )
    assert json.loads(out.stdout.splitlines()[-1]) == [False, True, True]
    assert "no broker connection yet" in out.stderr
