"""The REST API against its own OpenAPI schema over HTTP, as a client meets it: schemathesis
with every check, against the running daphne server with the default settings (DEBUG on), as a
customer and as staff.

tests/cpcc_site/test_api_fuzz.py does the same in-process (WSGI, DEBUG off); here the answers
come from the whole stack (daphne, every middleware, Django's own pages for what no view
answers): an id no URL pattern matches must get the API's JSON 404, never Django's HTML debug
page.

Every check includes "positive data acceptance": a request the schema admits must succeed. The
schema says what the API enforces about a request's form (non-blank names, coordinate ranges,
list sizes); a value another record holds already (a name in use) is a 409. What a schema
cannot say is documented as a 400 on the operations that have it, and accepted here as the
answer to a schema-valid request only there: a program's syntax (POST /vvs/, /vvs/dry-run/), an area's
geometry (a closed ring that does not cross itself), names that must exist in the sensor
catalog, and a webhook's host, which must resolve to a public address.
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import schemathesis
from drf_spectacular.generators import SchemaGenerator
from hypothesis import HealthCheck
from hypothesis import settings as hypothesis_settings
from rest_framework.authtoken.models import Token
from schemathesis.specs.openapi.checks import positive_data_acceptance

from tests.factories import UserFactory
from tests.live import Web

EXAMPLES = 15

# Operations whose bodies have rules beyond the schema (see the module's docstring; and an
# invitation to an address that is a member's already).
RULES_BEYOND_THE_SCHEMA = {
    "POST /api/v1/vvs/",
    "POST /api/v1/vvs/dry-run/",
    "POST /api/v1/vehicles/",
    "PATCH /api/v1/vehicles/{id}/",
    "POST /api/v1/customers/",
    "PUT /api/v1/customers/{id}/",
    "PATCH /api/v1/customers/{id}/",
    "POST /api/v1/webhooks/",
    "POST /api/v1/invites/",  # an address that is a member's already
    "GET /api/v1/service-levels/",  # since and until: an instant each, since before until
    "GET /api/v1/flights/",  # from and to likewise
    "GET /api/v1/flights/export.csv",
}


def _schema() -> dict:
    """The schema the server serves, generated from the code (no server, no database)."""
    from drf_spectacular.renderers import OpenApiJsonRenderer

    generated = SchemaGenerator().get_schema(request=None, public=True)
    return json.loads(OpenApiJsonRenderer().render(generated, renderer_context={}))


schema = schemathesis.openapi.from_dict(_schema()).exclude(path="/api/schema/")
# A request too large is refused for its size before anything else is looked at (413).
_rejection = schema.config.checks.negative_data_rejection
_rejection.expected_statuses = sorted({*_rejection.expected_statuses, "413"})


def accepts_what_the_schema_admits(ctx, response, case):
    """Positive data acceptance, with the documented 400 where the schema cannot say it all."""
    if response.status_code == 400 and case.operation.label in RULES_BEYOND_THE_SCHEMA:
        return None
    return positive_data_acceptance(ctx, response, case)


@pytest.fixture(scope="module")
def server(
    django_db_setup: None,
    broker_url: str,
    tmp_path_factory: pytest.TempPathFactory,
) -> Iterator[Web]:
    """daphne with the default settings (DEBUG on) on the test database, for this module."""
    tmp = tmp_path_factory.mktemp("live-api")
    web = Web(tmp, broker_url, var_dir=Path(tmp))
    web.env["DEBUG"] = "1"
    web.env["CPCC_API_RATE_USER"] = web.env["CPCC_API_RATE_ADDRESS"] = "100000/minute"
    web.start()
    try:
        yield web
    finally:
        web.stop()


def token_of(username: str, **fields) -> dict[str, str]:
    """The token header of a user made once per test (hypothesis calls the test many times)."""
    from accounts.models import User

    user = User.objects.filter(username=username).first() or UserFactory(
        username=username, **fields
    )
    return {"Authorization": f"Token {Token.objects.get_or_create(user=user)[0].key}"}


def _check(case, server: Web, headers: dict[str, str]) -> None:
    case.call_and_validate(
        base_url=server.url(""),
        headers=headers,
        additional_checks=[accepts_what_the_schema_admits],
        excluded_checks=[positive_data_acceptance],
    )


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
@schema.parametrize()
@hypothesis_settings(
    max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
def test_the_running_api_keeps_its_schema_for_a_customer(case, server, customer_a) -> None:
    _check(case, server, token_of("live-customer", customer=customer_a))


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
@schema.parametrize()
@hypothesis_settings(
    max_examples=EXAMPLES, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
)
def test_the_running_api_keeps_its_schema_for_staff(case, server) -> None:
    _check(case, server, token_of("live-staff", is_staff=True, is_superuser=True))


# Each role besides the two above (issue 57): every operation, a few cases each, in one
# hypothesis example per role (one flush of the database, not one per operation).
ROLE_CASES = 3


def _role_headers(role: str, customer) -> dict[str, str]:
    from django.contrib.auth.models import Group

    from accounts.roles import STAFF_GROUPS

    username = f"live-{role.replace(' ', '-')}"
    if role in STAFF_GROUPS:
        headers = token_of(username, is_staff=True)
        from accounts.models import User

        User.objects.get(username=username).groups.add(Group.objects.get(name=role))
        return headers
    return token_of(username, customer=customer, role=role)


@pytest.mark.django_db(transaction=True, serialized_rollback=True)
@pytest.mark.parametrize("role", ["developer", "viewer", "fleet manager", "pilot", "support"])
def test_the_running_api_keeps_its_schema_for_each_role(role, server, customer_a) -> None:
    from hypothesis import given
    from hypothesis import strategies as st

    headers = _role_headers(role, customer_a)
    operations = [result.ok() for result in schema.get_all_operations()]

    @given(data=st.data())
    @hypothesis_settings(
        max_examples=1, deadline=None, suppress_health_check=list(HealthCheck), derandomize=True
    )
    def every_operation(data) -> None:
        for operation in operations:
            for _ in range(ROLE_CASES):
                _check(data.draw(operation.as_strategy(), label=operation.label), server, headers)

    every_operation()
