"""A VV's journal: what a step is given of an answer is what a replay reads from the database."""

from __future__ import annotations

import pytest
from django.db import transaction

from cpcc_site.prepared import pipelined
from missions.models import VirtualVehicle
from vvm_worker.services import vv_submit
from vvm_worker.services.journal import JournalView, journal_append
from vvm_worker.services.store import jsonb_text

# Answers as sensors and programs make them: keys of every length and alphabet, numbers that
# JSON writes with an exponent, negative zero, text with control characters and beyond ASCII.
ENTRIES = [
    {"k": "task", "q": 3, "t": 1_764_300_000_123, "d": [{"lat": 48.1111, "lng": 12.8619}]},
    {
        "k": "task",
        "d": [
            {
                "co2": 1e-07,
                "big": 1.5e20,
                "zero": -0.0,
                "whole": 12.0,
                "tiny": 5e-324,
                "huge": 1.7976931348623157e308,
                "neg": -1.2345e-05,
                "int": 123456789012345678901234567890,
            }
        ],
    },
    {"k": "ret", "v": {"é": 'x\x01\x1fy\n\t"\\/\x7f\u2028z', "aa": [1, {"z": None, "y": True}]}},
    {"k": "ret", "v": {"b": "snow ❄ and 😀", "B": [], "ab": {}, "a": False, "": ""}},
]


@pytest.fixture
def vv(customer_a, ground_station, vvm_factory) -> VirtualVehicle:
    return vv_submit(customer=customer_a, name="VV", program="VV.log('x');", vvm=vvm_factory())


@pytest.mark.parametrize("entry", ENTRIES)
def test_an_answer_reads_back_from_the_database_as_the_step_was_given_it(
    vv, vvm_factory, entry
) -> None:
    with transaction.atomic(), pipelined():
        journal_append(vv, entry, vvm_factory())
    given = vv.__dict__["_journal_fresh"][0]
    stored = VirtualVehicle.objects.get(pk=vv.pk)  # what a replay elsewhere reads
    assert JournalView(stored)._texts(0, 1) == [given]


def test_an_answer_jsonb_does_not_store_as_written_is_read_back_as_stored(vv, vvm_factory) -> None:
    # A surrogate pair as two code points (as a JavaScript string may come): jsonb joins it.
    with transaction.atomic(), pipelined():
        journal_append(vv, {"k": "ret", "v": "\ud83d\ude00 and more"}, vvm_factory())
    given = vv.__dict__["_journal_fresh"][0]
    assert JournalView(VirtualVehicle.objects.get(pk=vv.pk))._texts(0, 1) == [given]


def test_jsonb_text_orders_keys_by_length_then_bytes_and_writes_numbers_plainly() -> None:
    assert jsonb_text({"bb": 1, "a": 2.5e-06, "é": -0.0, "c": [True, None, "\n"]}) == (
        '{"a": 0.0000025, "c": [true, null, "\\n"], "bb": 1, "é": 0.0}'
    )
    with pytest.raises(TypeError, match="keys are strings"):
        jsonb_text({1: "a key that is not a string"})
    with pytest.raises(ValueError, match="not a JSON number"):
        jsonb_text(float("nan"))
