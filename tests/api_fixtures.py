"""Fixtures shared by the REST API and CLI tests: API clients of both customers and of staff,
and a small mission really flown in-process (tasks, a rejection, camera images, storage, log).

The test packages import them in their conftest.py.
"""

from __future__ import annotations

import pytest
from rest_framework.authtoken.models import Token
from rest_framework.test import APIClient

from missions.models import VirtualVehicle, VVStatus
from tests.factories import VehicleFactory
from vvm_worker.services import vv_submit

# Reads a camera and CO2 at two points, stores each reading and a nested copy; one task that
# no RV can serve is rejected first.
MISSION = """
var cam = VV.sensor.get('Camera 640x480');
var co2 = VV.sensor.get('CO2');
try {
  VV.task.execute({type: 'point', position: new VV.types.LatLngAlt(10, 10, 50), tolerance: 2,
                   sensors: [co2]});
} catch (e) { VV.log('rejected:', e.name); }
var points = [new VV.types.LatLngAlt(48.1111, 12.8619, 50),
              new VV.types.LatLngAlt(48.1121, 12.8617, 50)];
for (var n = 0; n < points.length; ++n) {
  VV.task.execute({type: 'point', position: points[n], tolerance: 2, sensors: [cam, co2]},
    function (d) {
      VV.storage.store('p' + n + '.camera', d[0]);
      VV.storage.store('p' + n + '.co2', d[1]);
    });
}
VV.storage.store('all/readings', {points: [VV.storage.load('p0.camera'), [VV.storage.load('p1.camera')]],
                                  note: 'nested'});
VV.storage.store('plain key', 42);
VV.log('done:', VV.storage.list().length, 'keys');
"""
MISSION_KEYS = ["all/readings", "p0.camera", "p0.co2", "p1.camera", "p1.co2", "plain key"]


def token_client(user) -> APIClient:
    """An API client that authenticates with the user's token, as a script would."""
    client = APIClient()
    token, _ = Token.objects.get_or_create(user=user)
    client.credentials(HTTP_AUTHORIZATION=f"Token {token.key}")
    return client


@pytest.fixture
def api_a(user_a) -> APIClient:
    return token_client(user_a)


@pytest.fixture
def api_b(user_b) -> APIClient:
    client = APIClient()
    client.force_authenticate(user_b)  # session-style authentication
    return client


@pytest.fixture
def api_staff(staff) -> APIClient:
    return token_client(staff)


@pytest.fixture
def fleet_one(platform, ground_station):
    """One RV (Heli One, the paper's sensors) with its control loop on the platform."""
    vehicle = VehicleFactory(name="Heli One")
    platform.add_vehicle_loop(vehicle)
    return vehicle


@pytest.fixture
def mission(platform, fleet_one, customer_a) -> VirtualVehicle:
    """Customer A's VV after it has flown MISSION to its end."""
    vv = vv_submit(customer=customer_a, name="Survey", program=MISSION, vvm=platform.vvm)
    platform.drain()
    vv.refresh_from_db()
    assert vv.status == VVStatus.FINISHED, vv.error
    return vv
