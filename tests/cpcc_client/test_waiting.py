"""``cpcc status`` says what a VV waits for, in the API's words (its ``waiting``)."""

from __future__ import annotations

import argparse
from typing import Any

from cpcc_client import cli
from vvm_worker.services import vv_submit

PROGRAM = "VV.log('hello');"


class InProcessClient:
    """The CLI's client answered by the API in-process (DRF's test client, with a token)."""

    def __init__(self, api) -> None:
        self.api = api

    def call(self, method: str, path: str, **kwargs: Any) -> Any:
        response = self.api.generic(method, path)
        assert response.status_code == 200, response.content
        return response.json()


def status(api, vv_id: str, capsys) -> list[str]:
    code = cli.cmd_status(InProcessClient(api), argparse.Namespace(id=vv_id, json=False))
    assert code == cli.EXIT_OK
    return capsys.readouterr().out.splitlines()


def test_status_prints_what_a_queued_vv_waits_for_and_nothing_for_one_that_does_not(
    customer_a, ground_station, vvm_factory, api_a, capsys
) -> None:
    vvm = vvm_factory()  # nothing runs: the VVs stay where admission puts them
    customer_a.max_parallel_vvs = 1
    customer_a.save()
    running = vv_submit(customer=customer_a, name="first", program=PROGRAM, vvm=vvm)
    queued = vv_submit(customer=customer_a, name="second", program=PROGRAM, vvm=vvm)
    lines = status(api_a, str(queued.pk), capsys)
    assert "status    queued" in lines
    assert "waiting   in the queue behind 1 of your VVs (limit 1 in parallel)" in lines
    # On a ground station before its first step it waits for nothing yet.
    assert not [line for line in status(api_a, str(running.pk), capsys) if "waiting" in line]
