from tests.api_fixtures import (  # noqa: F401 - fixtures
    api_a,
    api_b,
    api_staff,
    fleet_one,
    mission,
)
