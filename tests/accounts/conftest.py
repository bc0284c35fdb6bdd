import pytest

from tests.accounts.receiver import Receiver, running_receiver
from tests.api_fixtures import (  # noqa: F401 - fixtures
    api_a,
    api_b,
    api_staff,
    fleet_one,
    mission,
)


@pytest.fixture
def receiver():
    """A webhook receiver on 127.0.0.1 (tests/accounts/receiver.py)."""
    yield from running_receiver()


@pytest.fixture(autouse=True)
def _fresh_last_used() -> None:
    """Token ids repeat between tests: what this process last wrote is forgotten."""
    from accounts.authentication import LAST_USED

    LAST_USED.clear()


__all__ = ["Receiver"]
