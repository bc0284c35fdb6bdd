"""Static files are served by the platform in every mode (WhiteNoise), and no page loads
anything from the internet."""

from __future__ import annotations

import gzip
import re
from pathlib import Path

import pytest
from django.conf import settings
from django.contrib.staticfiles.storage import staticfiles_storage
from django.core.management import call_command

ROOT = Path(settings.BASE_DIR)
# Static files, and ReDoc's bundle, which cpcc_site/docs.py serves made offline.
ASSET = re.compile(r"""(?:src|href)\s*=\s*["'](/static/[^"']+|/api/redoc/[^"']+\.js)["']""")


def _fetch(client, url: str, **headers: str):
    """GET a file; its body is in ``body`` (reading it to the end closes the file)."""
    response = client.get(url, **headers)
    if response.streaming:
        response.body = b"".join(response.streaming_content)
    else:
        response.body = response.content
    return response


@pytest.fixture
def production_static(settings, tmp_path: Path) -> Path:
    """Settings as with DEBUG off, and collectstatic run into a temporary STATIC_ROOT."""
    settings.DEBUG = False
    settings.STATIC_ROOT = tmp_path / "staticfiles"
    settings.STORAGES = {
        **settings.STORAGES,
        "staticfiles": {"BACKEND": "cpcc_site.static_storage.HashedStaticFiles"},
    }
    settings.WHITENOISE_USE_FINDERS = False
    settings.WHITENOISE_AUTOREFRESH = False
    call_command("collectstatic", interactive=False, verbosity=0)
    return settings.STATIC_ROOT


def test_with_debug_off_the_pages_link_hashed_files_that_whitenoise_serves(
    client, db, production_static
) -> None:
    page = client.get("/admin/login/")
    assert page.status_code == 200
    assets = ASSET.findall(page.text)
    base_css = next(
        a for a in assets if re.fullmatch(r"/static/admin/css/base\.[0-9a-f]{12}\.css", a)
    )
    for asset in assets:
        assert _fetch(client, asset).status_code == 200, asset

    css = _fetch(client, base_css)
    assert css["Content-Type"].startswith("text/css")
    assert "immutable" in css["Cache-Control"], "a hashed name may be cached for ever"
    assert b"--body-bg" in css.body

    leaflet = staticfiles_storage.url("vendor/leaflet/leaflet.js")
    assert re.fullmatch(r"/static/vendor/leaflet/leaflet\.[0-9a-f]{12}\.js", leaflet)
    js = _fetch(client, leaflet, HTTP_ACCEPT_ENCODING="gzip")
    assert js.status_code == 200
    assert js["Content-Type"].startswith("text/javascript")
    assert js["Content-Encoding"] == "gzip"
    assert b'version="1.9.4"' in gzip.decompress(js.body)
    assert _fetch(client, "/static/vendor/leaflet/nothing.js").status_code == 404


def test_with_debug_off_the_api_docs_assets_are_served(client, db, production_static) -> None:
    for page in ("/api/docs/", "/api/redoc/"):
        assets = ASSET.findall(client.get(page).text)
        assert any(a.endswith(".js") for a in assets), page
        for asset in assets:
            response = _fetch(client, asset)
            assert response.status_code == 200, asset
            assert response["Content-Type"].split(";")[0] in {
                "text/javascript",
                "text/css",
                "image/png",
                "image/svg+xml",
            }, asset


def test_with_debug_on_the_files_are_served_where_they_are_without_collectstatic(
    client, settings, tmp_path: Path
) -> None:
    settings.STATIC_ROOT = tmp_path / "never-collected"
    response = _fetch(client, "/static/vendor/leaflet/leaflet.css")
    assert response.status_code == 200
    assert response["Content-Type"].startswith("text/css")
    assert b".leaflet-container" in response.body
    widget = _fetch(client, "/static/js/admin/area-widget.js")
    assert widget["Content-Type"].startswith("text/javascript")
    assert _fetch(client, "/static/admin/css/base.css").status_code == 200


# Outside URLs a page may contain without loading anything: XML namespaces (inline SVG) and
# links a person may follow, in the vendored libraries (static/vendor/README.md).
ALLOWED_URLS = {
    "http://www.w3.org/2000/svg",
    "http://www.w3.org/1999/xlink",  # in Geoman's inline SVG icons
    "https://leafletjs.com",  # Leaflet's attribution link (the maps do not show it)
    "http://geoman.io",  # Geoman's package.json, bundled in its script
    "https://geoman.io",
    "https://github.com/geoman-io/leaflet-geoman/issues",
}
URL = re.compile(r"""https?://[^\s"'()<>\\`]+""")
COMMENTS = {
    ".html": re.compile(
        r"<!--.*?-->|\{#.*?#\}|\{%\s*comment\s*%\}.*?\{%\s*endcomment\s*%\}", re.DOTALL
    ),
    # Also the comments of SVG images inlined as data: URLs.
    ".css": re.compile(r"/\*.*?\*/|<!--.*?-->", re.DOTALL),
    # Block comments, and line comments that start a line or follow a space (never the // of
    # a URL, which follows a colon).
    ".js": re.compile(r"/\*.*?\*/|(?:^|(?<=\s))//[^\n]*", re.DOTALL | re.MULTILINE),
}
# Text a browser reads (images are not looked into); licences and notes are for people.
SCANNED = {".html", ".css", ".js", ".mjs", ".svg", ".json", ".txt"}
NOT_SCANNED = {"LICENSE", "THIRD-PARTY-LICENSES"}


def _source_files() -> list[Path]:
    files = [*(ROOT / "templates").rglob("*"), *(ROOT / "static").rglob("*")]
    return sorted(
        f for f in files if f.is_file() and f.suffix in SCANNED and f.name not in NOT_SCANNED
    )


def test_the_scanned_files_include_our_templates_and_the_vendored_libraries() -> None:
    names = {f.relative_to(ROOT).as_posix() for f in _source_files()}
    assert {
        "templates/admin/fleet/vehicle/overview.html",
        "static/vendor/leaflet/leaflet.js",
        "static/vendor/leaflet-geoman/leaflet-geoman.min.js",
        "static/css/admin-map.css",
    } <= names


@pytest.mark.parametrize("path", _source_files(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_template_or_static_file_refers_to_an_outside_url(path: Path) -> None:
    text = path.read_text(encoding="utf-8")
    comments = COMMENTS.get(path.suffix)
    if comments is not None:
        text = comments.sub("", text)
    outside = {u.rstrip(".,;") for u in URL.findall(text)} - ALLOWED_URLS
    assert not outside, f"{path.relative_to(ROOT)} refers to {sorted(outside)}"


# An inline SVG of a stylesheet: url('data:image/svg+xml,...') (single-quoted, as the vendored
# Leaflet-Geoman writes them).
INLINE_SVG = re.compile(r"url\('data:image/svg\+xml,(?P<svg>[^']*)'\)")


def test_with_debug_off_every_icon_of_the_area_editors_toolbar_is_a_whole_svg(
    client, db, production_static
) -> None:
    # The area editor's buttons (draw rectangle, polygon, edit, drag, erase) are inline SVGs
    # in Leaflet-Geoman's stylesheet. As served with DEBUG off (hashed, post-processed) each
    # must be the SVG it is in the source: a '#' written into a data URL ends it, and quotes
    # inside an attribute break the XML; either leaves an empty button.
    from urllib.parse import unquote
    from xml.etree import ElementTree

    source = (ROOT / "static/vendor/leaflet-geoman/leaflet-geoman.css").read_text()
    served_name = staticfiles_storage.stored_name("vendor/leaflet-geoman/leaflet-geoman.css")
    served = _fetch(client, settings.STATIC_URL + served_name).body.decode()
    icons = [m["svg"] for m in INLINE_SVG.finditer(served)]
    assert len(icons) >= 5
    assert icons == [m["svg"] for m in INLINE_SVG.finditer(source)]
    for svg in icons:
        assert "#" not in svg, svg[:200]
        ElementTree.fromstring(unquote(svg).removeprefix('<?xml version="1.0" encoding="UTF-8"?>'))
