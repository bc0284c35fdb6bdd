"""A VV's readings as files people open as they are: readings.csv, readings.geojson and
track.kml from the API and in results.zip, read back with standard readers, from a mission
really flown in-process; another customer gets 404, an anonymous caller is refused."""

from __future__ import annotations

import csv
import io
import json
import zipfile
from xml.etree import ElementTree as ET

import pytest
from rest_framework.test import APIClient
from shapely.geometry import Point, shape

from missions.api.results import READINGS_COLUMNS, track_kml
from missions.models import TaskStatus
from missions.readings import ReadingRow, image_file, reading_rows

NO_SUCH_ID = "00000000-0000-0000-0000-000000000000"
KML = "{http://www.opengis.net/kml/2.2}"


def vv_url(vv, rest: str) -> str:
    return f"/api/v1/vvs/{vv.pk}/{rest}"


def readings_of(vv) -> list[dict]:
    """Every reading the VV's tasks took, as the database keeps them, in time order."""
    tasks = vv.tasks.filter(status=TaskStatus.DONE).order_by("q", "index")
    readings = [(r["time"], k, r) for k, t in enumerate(tasks) for r in t.readings]
    return [r for _, _, r in sorted(readings, key=lambda item: item[:2])]


def expected_value(vv, reading: dict, picture: str) -> object:
    if reading["kind"] == "camera":
        return picture.format(vv=vv.pk, file=image_file(reading["image"]))
    return reading["value"]


def test_readings_csv_holds_every_reading_with_its_time_place_value_and_unit(
    mission, api_a
) -> None:
    response = api_a.get(vv_url(mission, "readings.csv"))
    assert response.status_code == 200
    assert response["Content-Type"] == "text/csv; charset=utf-8"
    assert 'filename="survey-' in response["Content-Disposition"]
    assert response["Content-Disposition"].endswith('-readings.csv"')
    table = csv.DictReader(io.StringIO(response.content.decode("utf-8")))
    assert tuple(table.fieldnames or ()) == READINGS_COLUMNS
    rows = list(table)
    readings = readings_of(mission)
    # Two tasks of a camera and CO2; the rejected task read nothing.
    assert len(rows) == len(readings) == 4
    picture = "http://testserver/api/v1/vvs/{vv}/images/{file}"
    for row, reading in zip(rows, readings, strict=True):
        assert row["time"] == reading["time"] and row["time"].endswith("Z")
        assert row["sensor"] == reading["sensor"] and row["kind"] == reading["kind"]
        where = reading["position"]
        assert (float(row["latitude"]), float(row["longitude"])) == (where["lat"], where["lng"])
        assert float(row["altitude_m"]) == where["alt"]
        value = expected_value(mission, reading, picture)
        if reading["kind"] == "scalar":
            assert float(row["value"]) == value and row["unit"] == reading["unit"] == "ppm"
        else:
            assert row["value"] == value and row["unit"] == ""
    assert [row["time"] for row in rows] == sorted(row["time"] for row in rows)
    tasks = {(t.q, t.index) for t in mission.tasks.filter(status=TaskStatus.DONE)}
    assert {(int(row["task_q"]), int(row["task_index"])) for row in rows} == tasks
    # A camera's value is the picture itself, for its owner.
    camera = next(row for row in rows if row["kind"] == "camera")
    image = api_a.get(camera["value"].removeprefix("http://testserver"))
    assert image.status_code == 200 and image["Content-Type"] == "image/png"


def test_readings_geojson_is_a_feature_collection_of_a_point_per_reading(mission, api_a) -> None:
    response = api_a.get(vv_url(mission, "readings.geojson"))
    assert response.status_code == 200
    assert response["Content-Type"] == "application/geo+json; charset=utf-8"
    assert response["Content-Disposition"].endswith('-readings.geojson"')
    collection = json.loads(response.content)
    assert collection["type"] == "FeatureCollection"
    features = collection["features"]
    readings = readings_of(mission)
    assert len(features) == len(readings) == 4
    picture = "http://testserver/api/v1/vvs/{vv}/images/{file}"
    for feature, reading in zip(features, readings, strict=True):
        assert feature["type"] == "Feature"
        assert feature["geometry"]["type"] == "Point"
        where = reading["position"]
        # RFC 7946: longitude, latitude, altitude.
        assert feature["geometry"]["coordinates"] == [where["lng"], where["lat"], where["alt"]]
        point = shape(feature["geometry"])
        assert isinstance(point, Point) and (point.x, point.y) == (where["lng"], where["lat"])
        properties = feature["properties"]
        assert properties["time"] == reading["time"]
        assert properties["sensor"] == reading["sensor"]
        assert properties["value"] == expected_value(mission, reading, picture)
        assert properties["unit"] == reading.get("unit", "")


def test_results_zip_holds_the_readings_and_the_flown_track_as_kml(mission, api_a) -> None:
    response = api_a.get(vv_url(mission, "results.zip"))
    archive = zipfile.ZipFile(io.BytesIO(b"".join(response.streaming_content)))
    names = set(archive.namelist())
    assert {"readings.csv", "readings.geojson", "track.kml"} <= names
    readings = readings_of(mission)

    rows = list(csv.DictReader(io.StringIO(archive.read("readings.csv").decode("utf-8"))))
    assert [row["time"] for row in rows] == [r["time"] for r in readings]
    # In the zip a camera's value names its picture in the zip, which is there.
    cameras = [row["value"] for row in rows if row["kind"] == "camera"]
    assert len(cameras) == 2 and all(name in names for name in cameras)
    assert all(name.startswith("images/") for name in cameras)
    features = json.loads(archive.read("readings.geojson"))["features"]
    assert [str(f["properties"]["value"]) for f in features] == [row["value"] for row in rows]

    kml = ET.fromstring(archive.read("track.kml"))
    assert kml.tag == f"{KML}kml"
    (line,) = kml.iter(f"{KML}LineString")
    assert line.findtext(f"{KML}altitudeMode") == "relativeToGround"
    flown = [
        tuple(float(n) for n in point.split(","))
        for point in line.findtext(f"{KML}coordinates").split()
    ]
    track = list(mission.track.order_by("t_s", "id").values_list("lng", "lat", "alt"))
    assert len(track) >= 2 and flown == track
    marks = list(kml.find(f"{KML}Document").find(f"{KML}Folder").iter(f"{KML}Placemark"))
    assert len(marks) == len(readings)
    whens = [mark.find(f"{KML}TimeStamp").findtext(f"{KML}when") for mark in marks]
    assert whens == [r["time"] for r in readings]
    co2 = [m for m in marks if m.findtext(f"{KML}name").startswith("CO2: ")]
    assert [m.findtext(f"{KML}name") for m in co2] == [
        f"CO2: {r['value']} ppm" for r in readings if r["sensor"] == "CO2"
    ]


def test_track_kml_is_the_flown_track_as_in_results_zip(mission, api_a) -> None:
    response = api_a.get(vv_url(mission, "track.kml"))
    assert response.status_code == 200
    assert response["Content-Type"] == "application/vnd.google-earth.kml+xml; charset=utf-8"
    assert 'filename="survey-' in response["Content-Disposition"]
    assert response["Content-Disposition"].endswith('-track.kml"')
    kml = ET.fromstring(response.content)
    assert kml.tag == f"{KML}kml"
    (line,) = kml.iter(f"{KML}LineString")
    flown = [
        tuple(float(n) for n in point.split(","))
        for point in line.findtext(f"{KML}coordinates").split()
    ]
    track = list(mission.track.order_by("t_s", "id").values_list("lng", "lat", "alt"))
    assert len(track) >= 2 and flown == track
    # The zip's file, but for a camera's value: the picture's URL here, as in readings.csv,
    # its file in the zip there.
    archive = zipfile.ZipFile(
        io.BytesIO(b"".join(api_a.get(vv_url(mission, "results.zip")).streaming_content))
    )
    in_zip = archive.read("track.kml")
    assert b"images/" in in_zip
    images = f"http://testserver/api/v1/vvs/{mission.pk}/images/".encode()
    assert response.content == in_zip.replace(b"images/", images)


@pytest.mark.parametrize("file", ["readings.csv", "readings.geojson", "track.kml"])
def test_another_customers_readings_answer_404_like_a_missing_vv(
    mission, api_a, api_b, client, user_a, file
) -> None:
    refused = api_b.get(vv_url(mission, file))
    assert refused.status_code == 404
    assert refused["Content-Type"] == "application/json"
    missing = api_b.get(vv_url(mission, file).replace(str(mission.pk), NO_SUCH_ID))
    assert refused.json() == missing.json()
    # The owner's session (the VV page's download links) and token both get the file.
    client.force_login(user_a)
    assert client.get(vv_url(mission, file)).status_code == 200
    assert api_a.get(vv_url(mission, file)).status_code == 200
    assert APIClient().get(vv_url(mission, file)).status_code in (401, 403)


def test_the_vv_page_links_the_readings_downloads(mission, client, user_a) -> None:
    client.force_login(user_a)
    page = client.get(f"/vvs/{mission.pk}/").text
    for file in ("readings.csv", "readings.geojson", "track.kml"):
        assert f'href="/api/v1/vvs/{mission.pk}/{file}"' in page


def test_rows_come_in_the_order_readings_were_taken_with_gps_fixes_and_no_junk() -> None:
    fix = {"lat": 48.1, "lng": 12.8, "alt": 50.2, "satellites": 11, "hdop": 0.8}
    where = {"lat": 48.1, "lng": 12.8, "alt": 50.0}
    later = {"sensor": "GPS", "kind": "gps", "time": "2025-01-01T00:02:00.000Z", "position": where}
    sooner = {
        "sensor": "CO2",
        "kind": "scalar",
        "time": "2025-01-01T00:01:00.000Z",
        "value": 418.5,
        "unit": "ppm",
    }
    # An executeAll batch: its second task was served first.
    rows = reading_rows(
        [(3, 0, [later | fix, "not a reading"]), (3, 1, [sooner]), (4, 0, None)],
        picture=lambda reference: f"url:{reference}",
    )
    assert [(row.sensor, row.task_q, row.task_index) for row in rows] == [
        ("CO2", 3, 1),
        ("GPS", 3, 0),
    ]
    assert rows[0].value == 418.5 and rows[0].lat is None  # no position: empty cells
    assert rows[1].value == "48.1, 12.8, 50.2" and rows[1].unit == ""
    geo_less = track_kml(name="VV", track=[], rows=rows)
    assert len(list(ET.fromstring(geo_less).iter(f"{KML}Placemark"))) == 1
    assert b"LineString" not in geo_less


def test_kml_escapes_names_and_values() -> None:
    row = ReadingRow("2025-01-01T00:00:00.000Z", 1.0, 2.0, 3.0, "<&>", "scalar", 1, "", 0, 0)
    document = ET.fromstring(track_kml(name="a & <b>", track=[], rows=[row]))
    assert document.find(f"{KML}Document").findtext(f"{KML}name") == "a & <b>"
    (mark,) = document.iter(f"{KML}Placemark")
    assert mark.findtext(f"{KML}name") == "<&>: 1"
