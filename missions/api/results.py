"""A VV's results as one zip file: what the VV endpoints show, plus its pictures."""

from __future__ import annotations

import json
import logging
import shutil
import tempfile
import zipfile
from typing import IO, Any

from django.core.files.storage import default_storage
from django.utils.text import slugify
from rest_framework.request import Request

from missions.api.serializers import (
    LogEntryOutSerializer,
    StaffTaskOutSerializer,
    TaskOutSerializer,
    VVSerializer,
)
from missions.models import VirtualVehicle
from missions.readings import image_file, map_camera_readings
from missions.selectors import (
    vv_image_references_for_user,
    vv_log_for_user,
    vv_storage_for_user,
    vv_tasks_for_user,
)

logger = logging.getLogger("cpcc.api")

IMAGES_DIR = "images"
# Results are built in memory up to this size, in a temporary file beyond.
SPOOL_BYTES = 32 * 1024 * 1024

README = """\
Results of the virtual vehicle {name} ({id}).

vv.json       the VV as GET /api/v1/vvs/{id}/ shows it
storage.json  its storage, {{key: value}}; a camera reading's "image" names its file in images/
tasks.json    its tasks as GET /api/v1/vvs/{id}/tasks/ shows them, images as in storage.json
log.txt       its log: time, level, message
images/       every picture its readings took
"""


def results_filename(vv: VirtualVehicle) -> str:
    """The name a results download is saved under: the VV's name and the start of its id."""
    return f"{slugify(vv.name) or 'vv'}-{str(vv.pk)[:8]}-results.zip"


def build_results_zip(*, request: Request, vv: VirtualVehicle) -> IO[bytes]:
    """Write the VV's results zip and return it, rewound: ``vv.json``, ``storage.json``,
    ``tasks.json``, ``log.txt``, ``README.txt`` and ``images/<file>`` for every picture.

    The caller has checked that the user may see the VV; the selectors check it again.
    """
    user = request.user
    context = {"request": request}
    known = vv_image_references_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]

    def in_zip(reading: dict[str, Any]) -> dict[str, Any]:
        reading.pop("image_url", None)
        if reading["image"] in known:
            reading["image"] = f"{IMAGES_DIR}/{image_file(reading['image'])}"
        return reading

    storage = {
        doc.key: map_camera_readings(doc.value, in_zip)
        for doc in vv_storage_for_user(user=user, vv_id=vv.pk)  # type: ignore[arg-type]
    }
    task_serializer = StaffTaskOutSerializer if user.is_staff else TaskOutSerializer
    tasks = [
        {**task, "readings": map_camera_readings(task["readings"], in_zip)}
        for task in task_serializer(
            vv_tasks_for_user(user=user, vv_id=vv.pk),  # type: ignore[arg-type]
            many=True,
            context=context,
        ).data
    ]
    log = LogEntryOutSerializer(
        vv_log_for_user(user=user, vv_id=vv.pk),  # type: ignore[arg-type]
        many=True,
        context=context,
    ).data

    out = tempfile.SpooledTemporaryFile(max_size=SPOOL_BYTES)  # noqa: SIM115 (returned open)
    with zipfile.ZipFile(out, "w", compression=zipfile.ZIP_DEFLATED) as archive:
        archive.writestr("README.txt", README.format(name=vv.name, id=vv.pk))
        archive.writestr("vv.json", _json(VVSerializer(vv, context=context).data))
        archive.writestr("storage.json", _json(storage))
        archive.writestr("tasks.json", _json(tasks))
        archive.writestr(
            "log.txt", "".join(f"{e['at']} {e['level']} {e['message']}\n" for e in log)
        )
        for reference in sorted(known):
            if not default_storage.exists(reference):
                logger.warning(
                    "image of a reading is missing", extra={"vv": str(vv.pk), "image": reference}
                )
                continue
            info = zipfile.ZipInfo(f"{IMAGES_DIR}/{image_file(reference)}")
            info.compress_type = zipfile.ZIP_STORED  # PNG and JPEG are compressed already
            with default_storage.open(reference, "rb") as src, archive.open(info, "w") as dst:
                shutil.copyfileobj(src, dst)
    out.seek(0)
    return out  # type: ignore[return-value]


def _json(data: Any) -> str:
    return json.dumps(data, indent=2, ensure_ascii=False, default=str) + "\n"
