"""factory_boy factories for the platform's models (the paper's Figure 3 area by default)."""

from __future__ import annotations

import factory
from django.utils.text import slugify

from accounts.models import Customer, User
from fleet.models import GroundStation, SensorType, Vehicle

# Heli One's area in the paper's Figure 3: a 0.005 x 0.005 degree box south-west of the depot.
AREA_ONE = [
    [48.109, 12.859],
    [48.109, 12.864],
    [48.114, 12.864],
    [48.114, 12.859],
    [48.109, 12.859],
]
AREA_TWO = [
    [48.109, 12.864],
    [48.109, 12.868],
    [48.114, 12.868],
    [48.114, 12.864],
    [48.109, 12.864],
]
PAPER_SENSORS = ["CO2", "Thermometer", "Camera 640x480", "GPS", "Barometer", "Altimeter", "NOx"]


class CustomerFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Customer
        django_get_or_create = ("name",)

    name = factory.Sequence(lambda n: f"Customer {n}")
    slug = factory.LazyAttribute(lambda c: slugify(c.name))


class UserFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = User
        django_get_or_create = ("username",)
        skip_postgeneration_save = True

    username = factory.Sequence(lambda n: f"user{n}")
    password = factory.PostGenerationMethodCall("set_password", "secret-pass-123")

    @factory.post_generation
    def _save(self, create, extracted, **kwargs):
        if create:
            self.save()


class GroundStationFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = GroundStation
        django_get_or_create = ("name",)

    name = factory.Sequence(lambda n: f"GS {n}")
    lat = 48.1132
    lng = 12.8598
    alt = 0.0


class VehicleFactory(factory.django.DjangoModelFactory):
    class Meta:
        model = Vehicle
        django_get_or_create = ("name",)
        skip_postgeneration_save = True

    name = factory.Sequence(lambda n: f"RV {n}")
    depot_lat = 48.1135
    depot_lng = 12.86
    depot_alt = 0.0
    area = factory.LazyFunction(lambda: [list(p) for p in AREA_ONE])
    min_altitude_m = 0.0
    max_altitude_m = 120.0
    max_speed_mps = 10.0

    @factory.post_generation
    def sensors(self, create, extracted, **kwargs):
        if create:
            names = PAPER_SENSORS if extracted is None else extracted
            self.sensors.set(SensorType.objects.filter(name__in=names))
