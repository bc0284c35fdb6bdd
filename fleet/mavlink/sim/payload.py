"""The payload: the vehicle's components besides the autopilot, the companion computer with the
gas sensors (``companion.py``) and the camera (``camera.py``), each sending with its own
MAVLink sender (component id and sequence numbers) and answering its own commands."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fleet.geo import Position
from fleet.mavlink.sim import camera as camera_protocol
from fleet.mavlink.sim import companion as companion_protocol
from fleet.mavlink.sim.camera import Camera, Shot
from fleet.mavlink.sim.commands import CommandServer, addressee
from fleet.mavlink.sim.companion import Companion, FieldSensors
from fleet.mavlink.sim.transport import Build
from fleet.mavlink.wire import mavlink


class Payload:
    """The companion and the camera. ``sender`` gives the send of a component (by id), the
    companion reads ``sensors`` where ``where`` says the vehicle is, ``shot`` says where it is
    for a picture, ``wall`` is the wall clock; ``seed`` is the world the images show, ``host``
    where their server listens."""

    COMPONENT_IDS = (companion_protocol.COMPONENT_ID, camera_protocol.COMPONENT_ID)

    def __init__(
        self,
        sender: Callable[[int], Callable[[Build], None]],
        sensors: FieldSensors,
        where: Callable[[], tuple[Position, float]],
        shot: Callable[[], Shot],
        wall: Callable[[], float],
        *,
        seed: int,
        host: str,
    ) -> None:
        send_companion = sender(companion_protocol.COMPONENT_ID)
        send_camera = sender(camera_protocol.COMPONENT_ID)
        self.companion = Companion(sensors, send_companion, where, wall)
        self.camera = Camera(send_camera, shot, wall, seed=seed, host=host)
        self._commands = {
            camera_protocol.COMPONENT_ID: CommandServer(
                lambda command, p, frame: self.camera.command(command, p), send_camera
            ),
            # The companion only reports: it says so to any command.
            companion_protocol.COMPONENT_ID: CommandServer(
                lambda command, p, frame: (int(mavlink.MAV_RESULT_UNSUPPORTED), None),
                send_companion,
            ),
        }

    def command_server(self, msg: Any) -> CommandServer | None:
        """The command server of the component a command is for; None: not the payload's."""
        return self._commands.get(addressee(msg))

    def open(self) -> None:
        """Start the camera's image server. Raises OSError."""
        self.camera.open()

    def close(self) -> None:
        self.camera.close()

    def tick(self) -> None:
        self.companion.tick()
        self.camera.tick()
