"""Keeping a vehicle row's version (``updated``) honest when only its sensors change."""

from __future__ import annotations

from typing import Any

from django.db.models.signals import m2m_changed
from django.dispatch import receiver
from django.utils import timezone

from fleet.models import Vehicle


@receiver(m2m_changed, sender=Vehicle.sensors.through)
def vehicle_sensors_changed(sender: Any, instance: Any, action: str, **kwargs: Any) -> None:
    if action not in ("post_add", "post_remove", "post_clear"):
        return
    now = timezone.now()
    if isinstance(instance, Vehicle):
        Vehicle.objects.filter(pk=instance.pk).update(updated=now)
        instance.updated = now
    else:  # changed from the sensor's side
        Vehicle.objects.filter(pk__in=kwargs.get("pk_set") or ()).update(updated=now)
