"""The parameter protocol over a MAVLink link: PARAM_REQUEST_READ and PARAM_SET answered
by PARAM_VALUE, with PX4's byte-wise integers (a part of ``MavlinkLink``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from fleet.mavlink import params as param_codec
from fleet.mavlink.errors import ParamRejected, ParamTimeout
from fleet.mavlink.exchange import LinkCore
from fleet.mavlink.modes import Autopilot
from fleet.mavlink.wire import encode_text


class Parameters(LinkCore):
    """Reading and writing the vehicle's parameters (see ``fleet.mavlink.link``)."""

    def param_get(self, name: str, *, timeout_s: float | None = None) -> float:
        """Read one parameter (PARAM_REQUEST_READ by name); returns its value.

        Integer parameters come back as whole floats (byte-wise encoding undone for PX4).
        Raises ParamTimeout when no PARAM_VALUE comes after every attempt (an unknown name
        gets no answer either), LinkLost when the link is down.
        """
        msg = self._param_exchange(
            name,
            lambda mav: mav.param_request_read_send(
                self._target(), self.target_component, encode_text(name, 16), -1
            ),
            timeout_s,
        )
        return self._decode_param(msg)

    def param_set(
        self,
        name: str,
        value: float,
        *,
        param_type: int | None = None,
        timeout_s: float | None = None,
    ) -> float:
        """Write one parameter and wait for the vehicle's PARAM_VALUE with the new value.

        ``param_type`` (MAV_PARAM_TYPE) is taken from an earlier PARAM_VALUE when not given
        (the parameter is read first if none was seen). Returns the value the vehicle holds.
        Raises ParamRejected (permanent) when the echo shows another value, ParamTimeout when
        no echo comes, ValueError when the value does not fit an integer type.
        """
        if param_type is None:
            param_type = self._param_types.get(name)
            if param_type is None:
                self.param_get(name, timeout_s=timeout_s)
                param_type = self._param_types.get(name, param_codec.REAL32)
        bytewise = self.autopilot is Autopilot.PX4
        wire = param_codec.encode(value, param_type, bytewise=bytewise)
        wanted = param_codec.decode(param_codec.as_float32(wire), param_type, bytewise=bytewise)
        msg = self._param_exchange(
            name,
            lambda mav: mav.param_set_send(
                self._target(), self.target_component, encode_text(name, 16), wire, param_type
            ),
            timeout_s,
        )
        held = self._decode_param(msg)
        if param_codec.as_float32(held) != param_codec.as_float32(wanted):
            raise ParamRejected(f"parameter {name}: wrote {value!r}, the vehicle holds {held!r}")
        return held

    def _param_exchange(
        self, name: str, send: Callable[[Any], None], timeout_s: float | None
    ) -> Any:
        timeout = self.command_timeout_s if timeout_s is None else timeout_s
        with self.waiting(
            lambda msg: msg.get_type() == "PARAM_VALUE" and msg.param_id == name
        ) as waiter:
            msg = self._ask(waiter, send, timeout)
        if msg is None:
            raise ParamTimeout(name, self.command_attempts)
        return msg

    def _decode_param(self, msg: Any) -> float:
        return param_codec.decode(
            float(msg.param_value),
            int(msg.param_type),
            bytewise=self.autopilot is Autopilot.PX4,
        )
