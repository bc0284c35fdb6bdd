"""The REST API against its own OpenAPI schema (schemathesis): as a customer and as staff.

Every operation gets generated requests, valid and invalid; every response must be what the
schema documents (status, content type, headers, body), none a server error, and invalid
requests must be refused (413, too large, counts as refused). Left out: schemathesis's
"positive data acceptance", which expects every request the schema admits to succeed; the
platform checks more than a schema can say (a program's syntax, an area that crosses itself,
an id that does not exist) and answers those with a documented 400 or 404.
"""

from __future__ import annotations

import pytest
import schemathesis
from django.core.signals import request_finished, request_started
from django.db import close_old_connections
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings
from rest_framework.authtoken.models import Token
from rest_framework.throttling import SimpleRateThrottle
from schemathesis.specs.openapi.checks import positive_data_acceptance

from cpcc_site.wsgi import application
from tests.factories import UserFactory

EXAMPLES = 25
SEMANTIC = [positive_data_acceptance]


# The schema comes from the application itself (generated from the code, no database).
schema = schemathesis.openapi.from_wsgi("/api/schema/?format=json", application).exclude(
    path="/api/schema/"
)
# An invalid request may also be refused for its size before anything else is looked at:
# 413 (CPCC_MAX_REQUEST_BYTES) is a refusal too, as it is for a valid one that large.
_rejection = schema.config.checks.negative_data_rejection
_rejection.expected_statuses = sorted({*_rejection.expected_statuses, "413"})


@pytest.fixture(autouse=True)
def _in_process_api(db, monkeypatch):
    # Hundreds of requests a minute from one address: beyond the production limits.
    monkeypatch.setattr(
        SimpleRateThrottle, "THROTTLE_RATES", {"user": "100000/min", "address": "100000/min"}
    )
    # The WSGI handler closes the database connection after each request; the test's
    # transaction must outlive them (Django's test client does the same).
    request_started.disconnect(close_old_connections)
    request_finished.disconnect(close_old_connections)
    yield
    request_started.connect(close_old_connections)
    request_finished.connect(close_old_connections)


def fuzz_user(username: str, **fields) -> dict[str, str]:
    """The token header of a user made once per test (hypothesis calls the test many times)."""
    from accounts.models import User

    user = User.objects.filter(username=username).first() or UserFactory(
        username=username, **fields
    )
    return token_for(user)


def token_for(user) -> dict[str, str]:
    return {"Authorization": f"Token {Token.objects.get_or_create(user=user)[0].key}"}


@schema.parametrize()
@hypothesis_settings(
    max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
def test_the_api_keeps_its_schema_for_a_customer(case, customer_a) -> None:
    case.call_and_validate(
        headers=fuzz_user("fuzz-customer", customer=customer_a), excluded_checks=SEMANTIC
    )


@schema.parametrize()
@hypothesis_settings(
    max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
def test_the_api_keeps_its_schema_for_staff(case) -> None:
    case.call_and_validate(
        headers=fuzz_user("fuzz-staff", is_staff=True, is_superuser=True), excluded_checks=SEMANTIC
    )
