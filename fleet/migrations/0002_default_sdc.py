"""Seed the system-wide device catalog with the default entries of DESIGN.md section 2."""

from django.db import migrations

from fleet.catalog import DEFAULT_SDC


def seed(apps, schema_editor):
    SensorType = apps.get_model("fleet", "SensorType")
    for entry in DEFAULT_SDC:
        SensorType.objects.update_or_create(
            name=entry["name"],
            defaults={
                "kind": entry["kind"],
                "unit": entry["unit"],
                "params": entry["params"],
                "privileged": entry.get("privileged", False),
                "description": entry["name"],
            },
        )


def unseed(apps, schema_editor):
    SensorType = apps.get_model("fleet", "SensorType")
    SensorType.objects.filter(name__in=[e["name"] for e in DEFAULT_SDC]).delete()


class Migration(migrations.Migration):
    dependencies = [("fleet", "0001_initial")]

    operations = [migrations.RunPython(seed, unseed)]
