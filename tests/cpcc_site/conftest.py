from tests.api_fixtures import fleet_one, mission  # noqa: F401 - fixtures
