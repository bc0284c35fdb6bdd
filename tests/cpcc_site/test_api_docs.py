"""The OpenAPI schema validates, and the browsable API docs work without internet."""

from __future__ import annotations

import re
from pathlib import Path
from urllib.parse import urlsplit

import pytest
import yaml
from django.conf import settings
from django.contrib.staticfiles import finders
from django.core.management import call_command

ASSET = re.compile(r"""(?:src|href)\s*=\s*["']([^"']+)["']""")


def test_the_schema_validates_without_warnings(tmp_path: Path) -> None:
    out = tmp_path / "schema.yaml"
    call_command("spectacular", "--validate", "--fail-on-warn", "--file", str(out))
    paths = yaml.safe_load(out.read_text())["paths"]
    for path in [
        "/api/v1/vvs/{id}/cancel/",
        "/api/v1/vvs/{id}/storage/",
        "/api/v1/vvs/{id}/storage/{key}/",
        "/api/v1/vvs/{id}/tasks/",
        "/api/v1/vvs/{id}/log/",
        "/api/v1/vvs/{id}/results.zip",
        "/api/v1/vvs/{id}/images/{file}",
        "/api/v1/sensors/",
        "/api/v1/vehicles/",
        "/api/v1/vehicles/{id}/maintenance/",
        "/api/v1/ground-stations/",
        "/api/v1/customers/",
    ]:
        assert path in paths, path


@pytest.mark.parametrize("page", ["/api/docs/", "/api/redoc/"])
def test_the_docs_pages_load_only_local_static_files(client, db, page: str) -> None:
    response = client.get(page)
    assert response.status_code == 200
    html = response.text
    assets = ASSET.findall(html)
    assert any(a.endswith(".js") for a in assets), assets
    for asset in assets:
        assert not urlsplit(asset).netloc, f"{asset} is not served by the platform itself"
        assert asset.startswith("/" + settings.STATIC_URL.strip("/") + "/"), asset
        assert finders.find(asset.split("/", 2)[2]), f"{asset} is not a static file"
    assert not re.search(r"https?://(?!testserver)", html), "no CDN or other outside URL"
