"""``cpcc submit --dry-run`` end to end against a live server: the report, and the exit code."""

from __future__ import annotations

from pathlib import Path

import pytest
from rest_framework.authtoken.models import Token

from cpcc_client import cli
from missions.models import VirtualVehicle

# The live server sees the test's data only when it is committed; the default SDC (a data
# migration) must be back for the tests that run after these.
pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)

GOOD = """var co2 = VV.sensor.get('CO2');
VV.task.execute({position: new VV.types.LatLngAlt(48.1111, 12.8619, 30), sensors: [co2]});
VV.log('read');
"""
# The second point is 70 km away from the paper's field.
FAR = (
    GOOD + "VV.task.execute({position: new VV.types.LatLngAlt(47.5, 11.9, 30), sensors: [co2]});\n"
)


@pytest.fixture
def cpcc(live_server, user_a, ground_station, heli_one, monkeypatch, capsys):
    """Run ``cpcc ARGS...`` as customer A, with GS Base and Heli One in service."""
    monkeypatch.setenv("CPCC_URL", live_server.url)
    monkeypatch.setenv("CPCC_TOKEN", Token.objects.create(user=user_a).key)

    def run(*args: str) -> tuple[int, str, str]:
        code = cli.main(list(args))
        out, err = capsys.readouterr()
        return code, out, err

    return run


def _program(tmp_path: Path, name: str, source: str) -> Path:
    path = tmp_path / name
    path.write_text(source)
    return path


def test_a_dry_run_names_the_task_no_vehicle_could_serve_and_fails(cpcc, tmp_path) -> None:
    far = _program(tmp_path, "far.js", FAR)
    code, out, err = cpcc("submit", "--dry-run", str(far))
    assert code == cli.EXIT_ERROR
    column = FAR.splitlines()[3].index("execute") + 1
    assert err.splitlines() == [
        f"{far}:4:{column}: no vehicle can serve the task at (47.500000, 11.900000) at 30 m: "
        "it is outside every operation area"
    ]
    assert "2 task(s), 1 that no vehicle in service could serve" in out
    assert "NOT SERVABLE" in out and "ends: failed: TaskRejectedError" in out
    assert not VirtualVehicle.objects.exists(), "a dry run submits nothing"


def test_a_dry_run_of_a_program_that_would_finish_succeeds(cpcc, tmp_path) -> None:
    code, out, err = cpcc("submit", "--dry-run", str(_program(tmp_path, "good.js", GOOD)))
    assert code == cli.EXIT_OK, err
    assert "1 task(s), 0 that no vehicle in service could serve" in out
    assert "ends: finished" in out and "quotas: within your quotas" in out
    assert "assumes: From the submission to the VV's end" in out
    assert not VirtualVehicle.objects.exists()


def test_a_dry_run_of_a_program_that_does_not_parse_says_where(cpcc, tmp_path) -> None:
    bad = _program(tmp_path, "bad.js", "var a = 1;\nvar b = ;\n")
    code, out, err = cpcc("submit", "--dry-run", str(bad))
    assert code == cli.EXIT_USAGE and "dry run" not in out
    assert err.strip() == f"{bad}:2:9: SyntaxError: Unexpected token ';'"
    code, _, err = cpcc("submit", "--dry-run", "--wait", str(bad))
    assert code == cli.EXIT_USAGE and "leave --wait out" in err
