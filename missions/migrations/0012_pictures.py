"""Pictures belong to a customer (issue 53): a VV may use a picture only when a VV of its
customer took or made it, and the pictures a VV makes count against its storage quota.

The pictures the VVs of a database received so far are found in their journals: a task's
camera readings (answers "done" and "part") and the pictures VV.image.crop and resize made
(answers "ret"). A message's answer ("msg") gives no customer a picture."""

import re

import django.db.models.deletion
from django.core.files.storage import default_storage
from django.db import migrations, models
from django.db.models import TextField
from django.db.models.functions import Cast

REFERENCE = re.compile(r"readings/([0-9a-f]{2})/\1[0-9a-f]{30}\.(?:png|jpg)")


def _taken(entry):
    """(reference, made) of the pictures a journal entry gave its VV."""
    kind, data = entry.get("k"), entry.get("data")
    if kind in ("done", "part") and isinstance(data, list):
        for reading in data:
            image = reading.get("image") if isinstance(reading, dict) else None
            if isinstance(image, str) and REFERENCE.fullmatch(image):
                yield image, False
    elif kind == "ret" and isinstance(data, dict):
        image = data.get("image")
        if isinstance(image, str) and REFERENCE.fullmatch(image):
            yield image, True


def _size(reference):
    try:
        return default_storage.size(reference)
    except OSError:
        return 0


def find_pictures(apps, schema_editor):
    JournalEntry = apps.get_model("missions", "JournalEntry")
    Picture = apps.get_model("missions", "Picture")
    VirtualVehicle = apps.get_model("missions", "VirtualVehicle")
    entries = (
        JournalEntry.objects.annotate(text=Cast("entry", output_field=TextField()))
        .filter(text__contains="readings/")
        .values_list("vv_id", "vv__customer_id", "entry")
        .order_by("vv_id", "seq")
    )
    seen = set()
    made_bytes = {}
    for vv_id, customer_id, entry in entries.iterator(chunk_size=2000):
        for reference, made in _taken(entry):
            if (customer_id, reference) in seen:
                continue
            seen.add((customer_id, reference))
            size = _size(reference) if made else 0
            Picture.objects.create(
                customer_id=customer_id, reference=reference, vv_id=vv_id, made=made, bytes=size
            )
            if made:
                made_bytes[vv_id] = made_bytes.get(vv_id, 0) + size
    for vv_id, size in made_bytes.items():
        VirtualVehicle.objects.filter(pk=vv_id).update(picture_bytes=size)


class Migration(migrations.Migration):
    dependencies = [("missions", "0011_vv_fillfactor")]

    operations = [
        migrations.AddField(
            model_name="virtualvehicle",
            name="picture_bytes",
            field=models.PositiveBigIntegerField(default=0),
        ),
        migrations.CreateModel(
            name="Picture",
            fields=[
                ("id", models.BigAutoField(auto_created=True, primary_key=True, serialize=False, verbose_name="ID")),
                ("reference", models.CharField(help_text="The file under MEDIA_ROOT.", max_length=64)),
                (
                    "made",
                    models.BooleanField(
                        default=False,
                        help_text="Made by VV.image.crop or resize (counts against storage).",
                    ),
                ),
                ("bytes", models.PositiveIntegerField(default=0)),
                (
                    "customer",
                    models.ForeignKey(
                        on_delete=django.db.models.deletion.CASCADE,
                        related_name="+",
                        to="accounts.customer",
                    ),
                ),
                (
                    "vv",
                    models.ForeignKey(
                        blank=True,
                        help_text="The VV that first received or made it.",
                        null=True,
                        on_delete=django.db.models.deletion.SET_NULL,
                        related_name="+",
                        to="missions.virtualvehicle",
                    ),
                ),
            ],
            options={
                "constraints": [
                    models.UniqueConstraint(
                        fields=("customer", "reference"), name="picture_per_customer"
                    )
                ],
            },
        ),
        migrations.RunPython(find_pictures, migrations.RunPython.noop),
    ]
