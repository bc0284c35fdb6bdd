"""The ``cpcc`` command end to end against a live server, run in-process."""

from __future__ import annotations

import json
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from PIL import Image
from rest_framework.authtoken.models import Token

import missions.api.views
from cpcc_client import cli
from missions.models import VirtualVehicle, VVStatus
from tests.api_fixtures import MISSION, MISSION_KEYS

# The live server sees the test's data only when it is committed; the default SDC (a data
# migration) must be back for the tests that run after these.
pytestmark = pytest.mark.django_db(transaction=True, serialized_rollback=True)


@pytest.fixture(autouse=True)
def _platform_behind_the_api(platform, monkeypatch) -> None:
    """VVs submitted through the API go to the in-process platform (instead of the Celery
    workers), which admits and flies them when the test drains it."""
    monkeypatch.setattr(missions.api.views, "platform_vvm", lambda: platform.vvm)


@pytest.fixture
def cpcc(live_server, user_a, monkeypatch, capsys):
    """Run ``cpcc ARGS...`` as customer A; returns (exit code, stdout, stderr)."""
    monkeypatch.setenv("CPCC_URL", live_server.url)
    monkeypatch.setenv("CPCC_TOKEN", Token.objects.create(user=user_a).key)

    def run(*args: str) -> tuple[int, str, str]:
        code = cli.main(list(args))
        out, err = capsys.readouterr()
        return code, out, err

    return run


@pytest.fixture
def program(tmp_path: Path) -> Path:
    path = tmp_path / "survey.js"
    path.write_text(MISSION)
    return path


def test_submit_status_list_log_and_cancel(cpcc, program) -> None:
    code, out, err = cpcc("submit", str(program), "--name", "first")
    assert code == 0, err
    vv_id = out.strip()
    assert VirtualVehicle.objects.get(pk=vv_id).name == "first"
    code, out, _ = cpcc("status", vv_id)
    assert code == 0 and "status    queued" in out and "tasks     0 done, 0 open" in out
    code, out, _ = cpcc("status", vv_id, "--json")
    assert json.loads(out)["name"] == "first"
    code, out, _ = cpcc("list")
    assert code == 0 and vv_id in out and "first" in out and out.startswith("ID")
    assert cpcc("list", "--status", "finished")[1].strip() == "no VVs with status finished"
    assert cpcc("log", vv_id) == (0, "", "")
    code, out, _ = cpcc("cancel", vv_id)
    assert code == 0 and out.strip() == f"{vv_id} cancelled"
    code, out, err = cpcc("cancel", vv_id)
    assert code == 1 and out == ""
    assert (
        err.strip()
        == "cpcc: 409 Conflict: 'first' has already ended (cancelled): there is nothing to cancel."
    )


def test_a_syntax_error_points_at_the_file_line_and_column(cpcc, tmp_path) -> None:
    bad = tmp_path / "bad.js"
    bad.write_text("var a = 1;\nvar b = ;\n")
    code, out, err = cpcc("submit", str(bad))
    assert code == 2 and out == ""
    assert err.strip() == f"{bad}:2:9: SyntaxError: Unexpected token ';'"
    assert not VirtualVehicle.objects.exists()


def test_submit_wait_polls_until_the_vv_finishes(
    cpcc, program, platform, fleet_one, monkeypatch
) -> None:
    def fly(seconds: float) -> None:
        # Instead of sleeping: the platform admits the queued VV and flies it to its end.
        assert seconds == 0.5
        platform.drain()

    monkeypatch.setattr(cli, "_sleep", fly)
    code, out, err = cpcc("submit", str(program), "--wait", "--poll", "0.5", "--timeout", "60")
    assert code == 0, err
    vv_id, status = out.split()
    assert status == "finished"
    assert VirtualVehicle.objects.get(pk=vv_id).status == VVStatus.FINISHED
    code, out, _ = cpcc("log", vv_id)
    assert "info    done: 6 keys" in out


def test_submit_wait_exits_non_zero_when_the_vv_fails_or_time_runs_out(
    cpcc, tmp_path, platform, ground_station, monkeypatch
) -> None:
    failing = tmp_path / "fail.js"
    failing.write_text("VV.log('about to fail');\nnull.boom;\n")
    monkeypatch.setattr(cli, "_sleep", lambda seconds: platform.drain())
    code, out, err = cpcc("submit", str(failing), "--wait")
    assert code == 1 and out.split()[1] == "failed"
    assert "TypeError" in err
    code, out, err = cpcc("submit", str(failing), "--wait", "--timeout", "0")
    assert code == 3 and out.split()[1] == "queued" and "gave up waiting after 0 s" in err


def test_results_download_and_extract(cpcc, mission, tmp_path, monkeypatch) -> None:
    target = tmp_path / "out.zip"
    code, out, err = cpcc("results", str(mission.pk), "-o", str(target))
    assert code == 0, err
    assert out.strip() == str(target)
    with zipfile.ZipFile(target) as archive:
        assert sorted(json.loads(archive.read("storage.json"))) == MISSION_KEYS
    monkeypatch.chdir(tmp_path)
    code, out, _ = cpcc("results", str(mission.pk))
    assert code == 0 and out.strip().startswith("survey-") and Path(out.strip()).exists()
    code, out, _ = cpcc("results", str(mission.pk), "--extract", str(tmp_path / "x"))
    assert code == 0
    images = sorted((tmp_path / "x" / "images").iterdir())
    assert len(images) == 2 and all(Image.open(p).size == (640, 480) for p in images)
    storage = json.loads((tmp_path / "x" / "storage.json").read_text())
    assert (tmp_path / "x" / storage["p0.camera"]["image"]).exists()


def test_another_customers_vv_is_not_found(cpcc, mission, live_server, user_b, monkeypatch) -> None:
    monkeypatch.setenv("CPCC_TOKEN", Token.objects.create(user=user_b).key)
    for command in ("status", "log", "cancel", "results"):
        code, out, err = cpcc(command, str(mission.pk))
        assert code == 1 and out == "", command
        assert err.startswith("cpcc: 404 Not Found: No virtual vehicle with this id"), err
    mission.refresh_from_db()
    assert mission.status == VVStatus.FINISHED


def test_a_missing_token_and_an_unreachable_server_say_what_to_do(cpcc, monkeypatch) -> None:
    monkeypatch.delenv("CPCC_TOKEN")
    code, _, err = cpcc("list")
    assert code == 2 and "set CPCC_TOKEN" in err
    monkeypatch.setenv("CPCC_TOKEN", "nope")
    code, _, err = cpcc("list")
    assert code == 1 and "401" in err and "Invalid token" in err
    monkeypatch.setenv("CPCC_URL", "http://127.0.0.1:9")
    code, _, err = cpcc("list")
    assert code == 1 and "cannot reach http://127.0.0.1:9/api/v1/vvs/" in err


def test_python_dash_m_runs_the_same_command() -> None:
    done = subprocess.run(
        [sys.executable, "-m", "cpcc_client", "--help"], capture_output=True, text=True, check=False
    )
    assert done.returncode == 0 and "submit" in done.stdout and "CPCC_TOKEN" in done.stdout


# --- several programs at once -------------------------------------------------------------------


@pytest.fixture
def requests_sent(monkeypatch) -> list[tuple[str, str]]:
    """(method, path) of every API call the command makes."""
    sent: list[tuple[str, str]] = []
    call = cli.Client.call

    def recording(self, method, path, **kwargs):
        sent.append((method, path))
        return call(self, method, path, **kwargs)

    monkeypatch.setattr(cli.Client, "call", recording)
    return sent


def test_several_programs_go_in_one_request_and_print_their_ids_in_order(
    cpcc, tmp_path, requests_sent, user_a
) -> None:
    files = []
    for name in ("north", "south", "east"):
        path = tmp_path / f"{name}.js"
        path.write_text(f"VV.log('{name}');\n")
        files.append(str(path))
    code, out, err = cpcc("submit", *files)
    assert code == 0, err
    assert requests_sent == [("POST", "/api/v1/vvs/")]
    ids = out.split()
    assert [VirtualVehicle.objects.get(pk=vv_id).name for vv_id in ids] == [
        "north",
        "south",
        "east",
    ]
    assert {vv.customer_id for vv in VirtualVehicle.objects.all()} == {user_a.customer_id}
    code, _, err = cpcc("submit", *files, "--name", "one")
    assert code == 2 and "--name names one VV" in err


def test_several_programs_with_errors_are_each_named_and_none_is_submitted(cpcc, tmp_path) -> None:
    fine, bad, worse = tmp_path / "fine.js", tmp_path / "bad.js", tmp_path / "worse.js"
    fine.write_text("VV.log('fine');\n")
    bad.write_text("var a = 1;\nvar b = ;\n")
    worse.write_text("VV.log(;\n")
    code, out, err = cpcc("submit", str(fine), str(bad), str(worse))
    assert code == 2 and out == ""
    assert err.splitlines() == [
        f"{bad}:2:9: SyntaxError: Unexpected token ';'",
        f"{worse}:1:8: SyntaxError: Unexpected token ';'",
        "cpcc: nothing was submitted",
    ]
    assert not VirtualVehicle.objects.exists()


def test_submit_wait_with_several_programs_waits_for_all_of_them(
    cpcc, tmp_path, platform, fleet_one, monkeypatch
) -> None:
    monkeypatch.setattr(cli, "_sleep", lambda seconds: platform.drain())
    good, failing = tmp_path / "good.js", tmp_path / "failing.js"
    good.write_text("VV.log('fine');\n")
    failing.write_text("null.boom;\n")
    code, out, err = cpcc("submit", str(good), str(failing), "--wait")
    assert code == 1
    ids, statuses = out.splitlines()[:2], out.splitlines()[2:]
    assert statuses == [f"{ids[0]} finished", f"{ids[1]} failed"]
    assert err.startswith(f"{failing}: ") and "TypeError" in err
