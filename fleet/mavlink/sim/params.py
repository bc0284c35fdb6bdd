"""The vehicle's side of the parameter protocol: PARAM_REQUEST_LIST, PARAM_REQUEST_READ and
PARAM_SET, each answered with PARAM_VALUE (values encoded as the flavour does: C cast on
ArduPilot, bytewise on PX4). An unknown name gets no answer, as on ArduPilot; a refused value
is answered with the value kept."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

from fleet.mavlink import params as param_codec
from fleet.mavlink.sim.flavours import Param
from fleet.mavlink.wire import encode_text


class ParamServer:
    """Keeps the parameters (by name, in the order PARAM_REQUEST_LIST streams them) and answers
    their messages. ``send`` sends a message (it gets pymavlink's MAVLink object).
    ``speeds`` are the flavour's speed parameters (name, ``VehicleSpec`` field, unit in m/s):
    a ground station setting one calls ``on_speed`` (field, m/s)."""

    def __init__(
        self,
        params: dict[str, Param],
        send: Callable[[Callable[[Any], None]], None],
        *,
        bytewise: bool,
        speeds: Sequence[tuple[str, str, float]],
        on_speed: Callable[[str, float], None],
    ) -> None:
        self._params = params
        self._send = send
        self._bytewise = bytewise
        self._speeds = speeds
        self._on_speed = on_speed

    def __contains__(self, name: str) -> bool:
        return name in self._params

    def value(self, name: str) -> float:
        """A parameter's value. Raises KeyError for an unknown name."""
        return self._params[name].value

    def get(self, name: str, default: float = 0.0) -> float:
        """A parameter's value, or ``default`` where the flavour has no such parameter."""
        param = self._params.get(name)
        return default if param is None else param.value

    def set(self, name: str, value: float) -> None:
        """Set a value from the vehicle's side (a command did it). Raises KeyError."""
        self._params[name].value = value

    def handle(self, msg: Any) -> bool:
        """Handle a message if it belongs to the parameter protocol; returns whether it did."""
        kind = msg.get_type()
        if kind == "PARAM_REQUEST_LIST":
            for name in self._params:
                self._send_value(name)
        elif kind == "PARAM_REQUEST_READ":
            self._on_request_read(msg)
        elif kind == "PARAM_SET":
            self._on_set_message(msg)
        else:
            return False
        return True

    def _send_value(self, name: str) -> None:
        names = list(self._params)
        param = self._params[name]
        wire = param_codec.encode(param.value, param.type, bytewise=self._bytewise)
        index = names.index(name)
        self._send(
            lambda mav: mav.param_value_send(
                encode_text(name, 16), wire, param.type, len(names), index
            )
        )

    def _on_request_read(self, msg: Any) -> None:
        names = list(self._params)
        if msg.param_index >= 0:
            if msg.param_index < len(names):
                self._send_value(names[msg.param_index])
        elif msg.param_id in self._params:
            self._send_value(msg.param_id)

    def _on_set_message(self, msg: Any) -> None:
        name = str(msg.param_id)
        param = self._params.get(name)
        if param is None:
            return
        value = param_codec.decode(float(msg.param_value), param.type, bytewise=self._bytewise)
        if not math.isfinite(value):
            self._send_value(name)  # refused: the echo shows the value kept
            return
        if param_codec.is_integer_type(param.type):
            value = float(round(value))
        param.value = value
        for speed_name, field, unit in self._speeds:
            if name == speed_name and value > 0:
                # A ground station changing a speed changes the kinematics from the next leg on.
                self._on_speed(field, value * unit)
        self._send_value(name)
