"""The camera component (MAV_COMP_ID_CAMERA) of the camera protocol, and the HTTP server its
images are fetched from.

It sends HEARTBEAT as MAV_TYPE_CAMERA, answers MAV_CMD_REQUEST_MESSAGE for CAMERA_INFORMATION
(and the older MAV_CMD_REQUEST_CAMERA_INFORMATION) and takes single images on
MAV_CMD_IMAGE_START_CAPTURE (param3 = 1): COMMAND_ACK, then CAMERA_IMAGE_CAPTURED with where it
was taken and ``file_url`` ``http://<host>:<port>/images/<index>.png``. The image is the default
catalog's "Camera 640x480" seen by ``fleet.simulation.render_camera`` at the capture's position,
heading and simulated time; it is rendered when first fetched, so capturing costs nothing.
"""

from __future__ import annotations

import logging
import re
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from fleet.catalog import DEFAULT_SDC
from fleet.geo import Position
from fleet.mavlink.wire import encode_text, mavlink
from fleet.simulation import SensorSpec, camera_settings, render_camera

logger = logging.getLogger("cpcc.mavsim")

COMPONENT_ID = int(mavlink.MAV_COMP_ID_CAMERA)
SDC_CAMERA = "Camera 640x480"
COMMANDS = frozenset(
    {
        mavlink.MAV_CMD_REQUEST_CAMERA_INFORMATION,
        mavlink.MAV_CMD_IMAGE_START_CAPTURE,
        mavlink.MAV_CMD_IMAGE_STOP_CAPTURE,
    }
)
MESSAGES = frozenset({mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION})
_HEARTBEAT_S = 1.0
_IMAGE_PATH = re.compile(r"^/images/(\d+)\.(png|jpg)$")


def sdc_camera(name: str = SDC_CAMERA) -> SensorSpec:
    """A camera of the default catalog, as the platform builds its spec. Raises KeyError."""
    for entry in DEFAULT_SDC:
        if entry["name"] == name:
            return SensorSpec(
                name=str(entry["name"]),
                kind=str(entry["kind"]),
                unit=str(entry.get("unit") or ""),
                params=dict(entry.get("params") or {}),
            )
    raise KeyError(f"no sensor named {name!r} in the default catalog")


@dataclass(frozen=True)
class Shot:
    """Where the vehicle is when an image is taken: position (above ground), its altitude
    above mean sea level and above home (metres), heading (degrees, None: unknown), the
    simulated time."""

    position: Position
    amsl_m: float
    relative_m: float
    heading_deg: float | None
    time_s: float


@dataclass(frozen=True)
class Capture:
    index: int
    shot: Shot
    time_utc_us: int


class ImageServer:
    """Serves the captures' images on ``host`` (port chosen by the OS) until ``stop``."""

    def __init__(self, host: str, image: Callable[[int], bytes | None], content_type: str) -> None:
        class Handler(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                match = _IMAGE_PATH.match(self.path)
                data = image(int(match.group(1))) if match else None
                if data is None:
                    self.send_error(404, "no such image")
                    return
                self.send_response(200)
                self.send_header("Content-Type", content_type)
                self.send_header("Content-Length", str(len(data)))
                self.end_headers()
                self.wfile.write(data)

            def log_message(self, format: str, *args: Any) -> None:
                logger.debug("mavsim image server: " + format, *args)

        self.host = host
        self._httpd = ThreadingHTTPServer((host, 0), Handler)
        self._httpd.daemon_threads = True
        self.port = int(self._httpd.server_address[1])
        self._thread = threading.Thread(
            target=self._httpd.serve_forever, args=(0.05,), name="mavsim images", daemon=True
        )
        self._thread.start()

    def stop(self) -> None:
        self._httpd.shutdown()
        self._httpd.server_close()
        self._thread.join(timeout=5.0)


class Camera:
    """The camera component. ``send`` sends from its component id, ``shot`` says where the
    vehicle is, ``wall`` is the wall clock (seconds since boot), ``seed`` the world the
    images show, ``host`` where the image server listens (and what ``file_url`` names)."""

    def __init__(
        self,
        send: Callable[[Callable[[Any], None]], None],
        shot: Callable[[], Shot],
        wall: Callable[[], float],
        *,
        seed: int,
        host: str,
        utc: Callable[[], float] = time.time,
    ) -> None:
        self._send = send
        self._shot = shot
        self._wall = wall
        self._seed = seed
        self._host = host
        self._utc = utc
        self.sensor = sdc_camera()
        self.settings = camera_settings(self.sensor)
        self._extension = "jpg" if self.settings.format == "jpeg" else "png"
        self._lock = threading.Lock()
        self._captures: list[Capture] = []
        self._images: dict[int, bytes] = {}
        self._server: ImageServer | None = None
        self._next_heartbeat = 0.0

    # The image server lives as long as the link is open.

    def open(self) -> None:
        if self._server is None:
            content_type = "image/jpeg" if self._extension == "jpg" else "image/png"
            self._server = ImageServer(self._host, self.image, content_type)

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None

    @property
    def port(self) -> int | None:
        return self._server.port if self._server is not None else None

    def url(self, index: int) -> str:
        return f"http://{self._host}:{self.port}/images/{index}.{self._extension}"

    @property
    def captures(self) -> list[Capture]:
        with self._lock:
            return list(self._captures)

    def image(self, index: int) -> bytes | None:
        """The encoded image of a capture (rendered on first use), or None if there is none."""
        with self._lock:
            if not 0 <= index < len(self._captures):
                return None
            capture = self._captures[index]
            cached = self._images.get(index)
        if cached is not None:
            return cached
        shot = capture.shot
        data = render_camera(
            self.sensor,
            shot.position,
            shot.time_s,
            seed=self._seed,
            heading_deg=shot.heading_deg or 0.0,
            epoch_s=capture.time_utc_us / 1e6,  # the caption prints when it was taken
        )
        with self._lock:
            self._images[index] = data
        return data

    # MAVLink

    def tick(self) -> None:
        wall = self._wall()
        if wall >= self._next_heartbeat:
            self._next_heartbeat = max(self._next_heartbeat + _HEARTBEAT_S, wall)
            self._send(
                lambda mav: mav.heartbeat_send(
                    mavlink.MAV_TYPE_CAMERA, mavlink.MAV_AUTOPILOT_INVALID, 0, 0,
                    mavlink.MAV_STATE_ACTIVE,
                )
            )  # fmt: skip

    def command(self, command: int, p: tuple[float, ...]) -> tuple[int, Callable[[], None] | None]:
        """Run a command addressed to the camera: its MAV_RESULT and what to send after the
        COMMAND_ACK."""
        accepted = int(mavlink.MAV_RESULT_ACCEPTED)
        if command == mavlink.MAV_CMD_REQUEST_MESSAGE:
            if round(p[0]) != mavlink.MAVLINK_MSG_ID_CAMERA_INFORMATION:
                return int(mavlink.MAV_RESULT_DENIED), None
            return accepted, self._send_information
        if command == mavlink.MAV_CMD_REQUEST_CAMERA_INFORMATION:
            return accepted, self._send_information if p[0] >= 0.5 else None
        if command == mavlink.MAV_CMD_IMAGE_START_CAPTURE:
            if round(p[2]) != 1:
                # Only single images (param3 = 1): no interval capture.
                return int(mavlink.MAV_RESULT_UNSUPPORTED), None
            capture = self._capture()
            return accepted, lambda: self._send_captured(capture)
        if command == mavlink.MAV_CMD_IMAGE_STOP_CAPTURE:
            return accepted, None
        return int(mavlink.MAV_RESULT_UNSUPPORTED), None

    def _capture(self) -> Capture:
        with self._lock:
            capture = Capture(len(self._captures), self._shot(), round(self._utc() * 1e6))
            self._captures.append(capture)
        logger.info("mavsim camera: image %d at %s", capture.index, capture.shot.position)
        return capture

    def _send_captured(self, capture: Capture) -> None:
        shot = capture.shot
        url = encode_text(self.url(capture.index), 205)
        self._send(
            lambda mav: mav.camera_image_captured_send(
                int(self._wall() * 1000) & 0xFFFFFFFF,
                capture.time_utc_us,
                0,  # camera_id: deprecated, 0 (the component id says which camera)
                round(shot.position.lat * 1e7),
                round(shot.position.lng * 1e7),
                round(shot.amsl_m * 1000),
                round(shot.relative_m * 1000),
                [1.0, 0.0, 0.0, 0.0],
                capture.index,
                1,  # capture_result: success
                url,
            )
        )

    def _send_information(self) -> None:
        settings = self.settings
        vendor = list(encode_text("CPCC", 32).ljust(32, b"\0"))
        model = list(encode_text("mavsim " + self.sensor.name, 32).ljust(32, b"\0"))
        self._send(
            lambda mav: mav.camera_information_send(
                int(self._wall() * 1000) & 0xFFFFFFFF,
                vendor,
                model,
                1,  # firmware version
                4.0,  # focal length, mm
                6.17,  # sensor size, mm (a 1/2.3" sensor)
                4.55,
                settings.width,
                settings.height,
                0,  # lens id
                mavlink.CAMERA_CAP_FLAGS_CAPTURE_IMAGE,
                0,  # no camera definition file
                b"",
            )
        )
