"""The MAVLink driver's sensors: readings from the vehicle's own messages and pictures by the
MAVLink camera protocol."""

from __future__ import annotations

import io
import logging
import time
import urllib.parse
import urllib.request
from collections.abc import Callable
from typing import Any

import PIL.Image

from fleet.driving import Sample, SensorFailure, SensorRead
from fleet.geo import Position
from fleet.mavlink.driver_state import _CAMERA, _MAX_PICTURE_BYTES
from fleet.mavlink.driver_telemetry import Telemetry
from fleet.mavlink.errors import (
    CommandDenied,
    MavlinkError,
)
from fleet.mavlink.wire import mavlink

logger = logging.getLogger("cpcc.mavlink.driver")


class Sensors(Telemetry):
    """Readings from the vehicle's own sensors and camera."""

    def read_sensor(self, read: SensorRead) -> Sample:
        """A reading of the vehicle's own sensor, the way ArduPilot and PX4 publish it: the
        next message that carries it, received from now on within ``read.timeout_s`` (never
        one from before the vehicle got here). GPS and altitude: GLOBAL_POSITION_INT (with
        GPS_RAW_INT's satellites and HDOP); pressure and temperature: SCALED_PRESSURE;
        battery: SYS_STATUS; a named value: NAMED_VALUE_FLOAT of that name from any
        component of the vehicle. Raises SensorFailure when it does not come."""
        quantity = str(read.params.get("quantity", "")).lower()
        if read.source == "named_value":
            what = f"NAMED_VALUE_FLOAT {read.name!r}"
            msg = self._next(
                lambda m: m.get_type() == "NAMED_VALUE_FLOAT" and _text(m.name) == read.name,
                read,
                what,
                any_component=True,
            )
            return self._sample({"value": round(float(msg.value), 4)})
        if read.source == "camera":
            return self._capture(read)
        if read.source != "telemetry":
            raise SensorFailure(f"this vehicle has no {read.source} source", where=read.sensor)
        if read.kind == "gps" or quantity == "altitude":
            msg = self._next(_is("GLOBAL_POSITION_INT"), read, "GLOBAL_POSITION_INT")
            if msg.lat == 0 and msg.lon == 0:
                raise SensorFailure("the autopilot has no position fix", where=read.sensor)
            alt = self.depot.alt + msg.relative_alt / 1000
            if read.kind != "gps":
                return self._sample({"value": round(alt, 2)})
            fields: dict[str, Any] = {"lat": msg.lat / 1e7, "lng": msg.lon / 1e7, "alt": alt}
            raw = self.link.last_message("GPS_RAW_INT")
            if raw is not None:
                fields["satellites"] = (
                    None if raw.satellites_visible == 255 else raw.satellites_visible
                )
                fields["hdop"] = None if raw.eph == 65535 else round(raw.eph / 100, 2)
            return self._sample(fields)
        if quantity in ("pressure", "temperature"):
            msg = self._next(_is("SCALED_PRESSURE"), read, "SCALED_PRESSURE")
            value = msg.press_abs if quantity == "pressure" else msg.temperature / 100
            return self._sample({"value": round(float(value), 2)})
        if quantity == "battery":
            msg = self._next(
                lambda m: m.get_type() == "SYS_STATUS" and m.battery_remaining >= 0,
                read,
                "SYS_STATUS with the battery's charge",
            )
            return self._sample({"value": float(msg.battery_remaining)})
        raise SensorFailure(
            f"the autopilot's telemetry has no {quantity or read.kind}", where=read.sensor
        )

    def _next(
        self,
        match: Callable[[Any], bool],
        read: SensorRead,
        what: str,
        *,
        any_component: bool = False,
    ) -> Any:
        if not self.link.link_ok:
            raise SensorFailure("the vehicle's link is down", where=f"{self.name}: {read.sensor}")
        msg = self.link.next_message(match, read.timeout_s, any_component=any_component)
        if msg is None:
            raise SensorFailure(
                f"no reading within {read.timeout_s:g} s",
                where=f"{self.name}: {read.sensor} ({what})",
            )
        return msg

    def _capture(self, read: SensorRead) -> Sample:
        """A picture through the MAVLink camera protocol: MAV_CMD_IMAGE_START_CAPTURE (one
        image) to the camera component, its CAMERA_IMAGE_CAPTURED (time and position of the
        capture, the picture's URI), then the picture fetched from that URI."""
        where = f"{self.name}: {read.sensor} (camera {_CAMERA})"
        if not self.link.link_ok:
            raise SensorFailure("the vehicle's link is down", where=where)
        deadline = time.monotonic() + read.timeout_s
        self._captures += 1
        sequence = self._captures

        def is_captured(msg: Any) -> bool:
            return bool(
                msg.get_type() == "CAMERA_IMAGE_CAPTURED" and msg.get_srcComponent() == _CAMERA
            )

        with self.link.waiting(is_captured, any_component=True) as captured:
            try:
                self.link.command_long(
                    mavlink.MAV_CMD_IMAGE_START_CAPTURE,
                    [0, 0, 1, sequence],
                    component=_CAMERA,
                    timeout_s=min(1.0, read.timeout_s),
                )
            except CommandDenied as exc:
                raise SensorFailure(
                    "the camera refused to take a picture", where=f"{where}: {exc}"
                ) from exc
            except MavlinkError as exc:
                raise SensorFailure("the camera did not answer", where=f"{where}: {exc}") from exc
            msg = captured.get(deadline - time.monotonic())
        if msg is None:
            raise SensorFailure(f"no picture within {read.timeout_s:g} s", where=where)
        if msg.capture_result != 1:
            raise SensorFailure("the camera could not take the picture", where=where)
        url = _text(msg.file_url)
        image, fmt, width, height = _fetch_picture(
            url, max(0.1, deadline - time.monotonic()), where
        )
        taken_ms = msg.time_utc // 1000 if msg.time_utc > 0 else int(time.time() * 1000)
        try:
            at = Position(msg.lat / 1e7, msg.lon / 1e7, self.depot.alt + msg.relative_alt / 1000)
        except ValueError:
            at = self._position
        fields = {"width": width, "height": height, "format": fmt}
        return Sample(fields=fields, epoch_ms=int(taken_ms), position=at, image=image)

    def _sample(self, fields: dict[str, Any]) -> Sample:
        """The reading as the vehicle took it: now (the vehicle's message just came) and where
        its telemetry says it is."""
        return Sample(fields=fields, epoch_ms=int(time.time() * 1000), position=self._position)


def _is(kind: str) -> Callable[[Any], bool]:
    return lambda msg: bool(msg.get_type() == kind)


def _text(value: Any) -> str:
    """A MAVLink char[] field as text (pymavlink gives str or bytes, NUL-padded or not)."""
    if isinstance(value, bytes):
        value = value.decode("ascii", errors="replace")
    return str(value).rstrip("\x00")


def _fetch_picture(url: str, timeout_s: float, where: str) -> tuple[bytes, str, int, int]:
    """The picture a camera published at ``url`` (http or https), checked to be a PNG or a
    JPEG: its bytes, format ("png" or "jpeg"), width and height."""
    if urllib.parse.urlsplit(url).scheme not in ("http", "https"):
        raise SensorFailure("the camera gave no picture address", where=f"{where}: {url!r}")
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as answer:
            data = answer.read(_MAX_PICTURE_BYTES + 1)
    except (OSError, ValueError) as exc:
        raise SensorFailure(
            "the camera's picture could not be fetched", where=f"{where}: {url}: {exc}"
        ) from exc
    if len(data) > _MAX_PICTURE_BYTES:
        raise SensorFailure("the camera's picture is too large", where=f"{where}: {url}")
    try:
        with PIL.Image.open(io.BytesIO(data)) as picture:
            fmt, width, height = str(picture.format or "").lower(), picture.width, picture.height
    except (OSError, ValueError) as exc:
        raise SensorFailure(
            "the camera's picture is not an image", where=f"{where}: {url}"
        ) from exc
    if fmt not in ("png", "jpeg"):
        raise SensorFailure(
            f"the camera's picture is {fmt or 'unknown'}, not PNG or JPEG", where=where
        )
    return data, fmt, width, height
