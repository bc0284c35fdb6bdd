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
        "/api/v1/vvs/{id}/messages/",
        "/api/v1/vvs/{id}/results.zip",
        "/api/v1/vvs/{id}/readings.csv",
        "/api/v1/vvs/{id}/readings.geojson",
        "/api/v1/vvs/{id}/track.kml",
        "/api/v1/vvs/{id}/images/{file}",
        "/api/v1/sensors/",
        "/api/v1/vehicles/",
        "/api/v1/vehicles/{id}/maintenance/",
        "/api/v1/ground-stations/",
        "/api/v1/customers/",
    ]:
        assert path in paths, path


@pytest.mark.parametrize("docs_page", ["/api/docs/", "/api/redoc/"])
def test_the_docs_pages_load_only_local_static_files(client, db, docs_page: str) -> None:
    response = client.get(docs_page)
    assert response.status_code == 200
    html = response.text
    assets = ASSET.findall(html)
    assert any(a.endswith(".js") for a in assets), assets
    for asset in assets:
        assert not urlsplit(asset).netloc, f"{asset} is not served by the platform itself"
        if asset == "/api/redoc/redoc.standalone.js":  # the sidecar's bundle, made offline
            continue
        assert asset.startswith("/" + settings.STATIC_URL.strip("/") + "/"), asset
        assert finders.find(asset.split("/", 2)[2]), f"{asset} is not a static file"
    assert not re.search(r"https?://(?!testserver)", html), "no CDN or other outside URL"


def test_redocs_bundle_loads_nothing_from_the_internet(client, db) -> None:
    response = client.get("/api/redoc/redoc.standalone.js")
    assert response.status_code == 200 and response["Content-Type"] == "text/javascript"
    bundle = b"".join(response) if response.streaming else response.content
    assert b"Redoc" in bundle and len(bundle) > 500_000
    assert b"https://cdn.redoc.ly" not in bundle
    assert b"/static/img/favicon.svg" in bundle


def test_the_site_has_an_icon(client, db) -> None:
    response = client.get("/favicon.ico")
    assert response.status_code == 301
    assert client.get(response["Location"]).status_code == 200
