"""``manage.py mavsim NAME``: a MAVLink-speaking simulated vehicle for one vehicle of the fleet.

It moves like the vehicle's record says (depot, maximum speed, climb and dive rates, turn
rate, battery endurance) and speaks MAVLink like ArduCopter (``--frame copter``), ArduRover
(``rover``, ``boat``) or ArduSub (``sub``), so the RV worker's MAVLink driver, MAVProxy or
QGroundControl can fly it. The frame defaults to the one of the vehicle's kind (a copter for an
aerial vehicle, a rover for a ground one, a boat for a surface one, a sub for an underwater
one). Unless ``--no-payload``, it also carries a companion computer
sending the simulated field's CO2 and NOx and a camera whose images it serves over HTTP
(``--field-seed`` picks that world). Runs in the foreground until Ctrl-C or SIGTERM.
"""

from __future__ import annotations

import argparse
import signal
import threading
from typing import Any

from django.conf import settings
from django.core.management.base import BaseCommand, CommandError, CommandParser

from fleet.mavlink.endpoint import mirror_endpoint
from fleet.mavlink.errors import LinkError
from fleet.mavlink.sim import FLAVOURS, FRAME_OF_KIND, FRAMES, MavSim
from fleet.selectors import vehicle_list
from fleet.simulation.vehicle import VehicleSpec


class Command(BaseCommand):
    help = (
        "Run a MAVLink-speaking simulated vehicle (ArduCopter, ArduRover or ArduSub) for one "
        "vehicle: its depot, speeds, rates and battery come from the database."
    )

    def add_arguments(self, parser: CommandParser) -> None:
        parser.add_argument("name", help="the vehicle's name")
        parser.add_argument(
            "--connection",
            help=(
                "where to listen or send, e.g. udpin:127.0.0.1:14560 (default: the other end "
                "of the vehicle's driver_url, e.g. udpin:H:P for udpout:H:P)"
            ),
        )
        parser.add_argument(
            "--speed",
            type=float,
            default=None,
            help="time acceleration (default CPCC_SIM_SPEED; 0: every flight ends at once)",
        )
        parser.add_argument("--system-id", type=int, default=1, help="MAVLink system id")
        parser.add_argument("--autopilot", choices=sorted(FLAVOURS), default="ardupilot")
        parser.add_argument(
            "--frame",
            choices=FRAMES,
            default=None,
            help=(
                "what it is: copter (ArduCopter or PX4), rover or boat (ArduRover), sub "
                "(ArduSub); default: the frame of the vehicle's kind"
            ),
        )
        parser.add_argument(
            "--battery", type=float, default=1.0, help="the charge it starts with, 0..1"
        )
        parser.add_argument(
            "--field-seed",
            type=int,
            default=0,
            help="seed of the simulated sensor field its sensors read (the platform's is 0)",
        )
        parser.add_argument(
            "--payload",
            action=argparse.BooleanOptionalAction,
            default=True,
            help="the companion computer (CO2, NOx) and the camera as MAVLink components",
        )
        parser.add_argument(
            "--camera-host",
            default="127.0.0.1",
            help="where the camera's image server listens, and the host its image URLs name",
        )

    def handle(self, *args: Any, **options: Any) -> None:
        name = options["name"]
        vehicle = vehicle_list().filter(name=name).first()
        if vehicle is None:
            known = ", ".join(v.name for v in vehicle_list()) or "none"
            raise CommandError(f"no vehicle named {name!r} (vehicles: {known})")
        connection = options["connection"]
        try:
            if not connection:
                if not vehicle.driver_url:
                    raise CommandError(f"{name} has no driver_url: give --connection")
                connection = mirror_endpoint(vehicle.driver_url)
            speed = settings.CPCC_SIM_SPEED if options["speed"] is None else options["speed"]
            frame = options["frame"] or FRAME_OF_KIND[vehicle.kind]
            sim = MavSim(
                connection,
                spec=VehicleSpec(
                    max_speed_mps=vehicle.max_speed_mps,
                    climb_rate_mps=vehicle.climb_rate_mps,
                    battery_s=vehicle.battery_s,
                    dive_rate_mps=vehicle.dive_rate_mps,
                    turn_rate_dps=vehicle.turn_rate_dps,
                ),
                depot=vehicle.depot,
                speed=speed,
                system_id=options["system_id"],
                autopilot=options["autopilot"],
                frame=frame,
                battery=options["battery"],
                name=name,
                field_seed=options["field_seed"],
                payload=options["payload"],
                camera_url_host=options["camera_host"],
            )
        except (LinkError, ValueError) as exc:
            raise CommandError(str(exc)) from None

        stop = threading.Event()
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, lambda *_: stop.set())
        if FRAME_OF_KIND[vehicle.kind] != frame:
            self.stderr.write(
                f"mavsim {name}: a {frame} for a vehicle configured as {vehicle.kind}: the "
                "platform's driver will refuse it"
            )
        self.stdout.write(
            f"mavsim {name}: {options['autopilot']} {frame} on {sim.endpoint} "
            f"(system {options['system_id']}, speed {speed:g})"
        )
        self.stdout.flush()
        try:
            sim.serve(stop, ready=lambda: self._ready(sim))
        except LinkError as exc:
            raise CommandError(str(exc)) from None
        self.stdout.write(f"mavsim {name}: stopped")

    def _ready(self, sim: MavSim) -> None:
        if sim.camera_port is not None:
            self.stdout.write(
                f"mavsim {sim.name}: camera images on "
                f"http://{sim.camera_url_host}:{sim.camera_port}/images/"
            )
            self.stdout.flush()
