"""The control loop's battery: whether a way fits what is left with the reserve, going home
when it runs low, recharging."""

from __future__ import annotations

import dataclasses
import logging

from fleet.geo import Position
from vvm_worker.control.legs import Legs
from vvm_worker.control.state import _percent
from vvm_worker.control.types import ACTIVE, CHARGE_POLL_S, CHARGING

logger = logging.getLogger("cpcc.executor")


class Battery(Legs):
    """The battery: the reserve, running low, recharging."""

    def _within_battery(self, now: float, way: list[Position]) -> bool:
        """Whether the vehicle can fly ``way`` and home from its end with its reserve left."""
        remaining = self.driver.battery_remaining_s(now)
        if remaining is None:
            return True
        need = self._way_s(way, now) + self._time_home_s(way[-1])
        if remaining - need >= self.reserve_s:
            return True
        if self.driver.is_landed_at(now) and remaining >= (self.config.battery_s or 0.0):
            # Full, and still too far: no charge helps; the mapper does not know the range.
            logger.warning("task beyond the battery's range", extra=self._log())
            return True
        return False

    def _run_low(self) -> None:
        """Hand the work over and go home to recharge: the VVs aboard move to RVs that can
        serve them (or wait), and this RV takes no work until it is full again."""
        logger.info(
            "%s: battery too low for the next task: home to recharge",
            self.name,
            extra={**self._log(), "battery": self.battery_fraction(self.clock())},
        )
        self.store.set_status(CHARGING, reason="battery too low for the next task")
        self.status = CHARGING

    def _charge(self, now: float) -> None:
        if self._charged_at is not None:
            return
        if self.driver.measures_battery:
            self._charged_at = now  # under way until the vehicle reports a charged battery
            logger.info(
                "%s: waiting for a charged battery (%s, back in service from %.0f %%)",
                self.name,
                _percent(self.battery_fraction(now)),
                100 * self.config.resume,
                extra=self._log(),
            )
            self.scheduler.call_at(now + CHARGE_POLL_S, self._charge_check)
            return
        self._charged_at = self.driver.recharge(now, self.config.recharge_s)
        self.scheduler.call_at(self._charged_at, self._charged)

    def _charge_check(self) -> None:
        """A measured battery: back into service when it reports ``config.resume`` or more
        (charged, or swapped), else look again; nothing more once the RV left ``charging``
        (a person decided otherwise)."""
        now = self.clock()
        if self.store.status() != CHARGING:
            self._charged_at = None
            return
        fraction = self.battery_fraction(now)
        if fraction is None or fraction >= self.config.resume:
            self._charged()
            return
        self.scheduler.call_at(now + CHARGE_POLL_S, self._charge_check)

    def set_battery(self, battery_s: float | None) -> None:
        """The vehicle's endurance was reconfigured: plan with it from now on."""
        self.config = dataclasses.replace(self.config, battery_s=battery_s)
        self.reserve_s = self.config.reserve * battery_s if battery_s else 0.0

    def _charged(self) -> None:
        self._charged_at = None
        logger.info("%s charged", self.name, extra=self._log())
        # Back into service, unless the provider decided otherwise meanwhile.
        self.store.set_status(ACTIVE, expected=CHARGING, reason="charged")
        self.wake()

    def wake(self) -> None:
        """Re-plan: the vehicle's tasks or status changed (``ControlLoop``)."""
        raise NotImplementedError
