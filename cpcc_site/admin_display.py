"""Numbers and times in the admin as what they mean, not as the floats the database keeps.

A position to 6 decimals of a degree (about 0.1 m), altitudes and distances to 0.1 m, speeds
to 0.1 m/s, durations to 0.1 s, a time on the platform clock as a UTC date and time: more
digits (``6831.406656359808``) only hide the ones that matter. The admin's lists and change
pages show a float field through a display method made here (``rounded``, ``duration``,
``moment``), named in ``list_display``, ``readonly_fields`` and fieldsets like a field.

A size the database keeps in bytes (a customer's storage, heap and message quotas) is entered
and shown in MB or KB through ``SizeField``, a form field: ``10`` for 10,485,760 bytes.
"""

from __future__ import annotations

import datetime as dt
import math
from collections.abc import Callable
from decimal import ROUND_HALF_EVEN, Decimal
from typing import Any

from django import forms
from django.contrib import admin
from django.contrib.admin.widgets import AdminBigIntegerFieldWidget
from django.core.exceptions import ValidationError

# How many decimals each kind of number means something to.
DEGREES = 6  # latitude and longitude: 1e-6 degree is about 0.1 m
METRES = 1  # altitudes, distances
SPEED = 1  # metres per second


def number_text(value: float, digits: int, unit: str = "") -> str:
    """``value`` rounded to ``digits`` decimals, thousands separated, with its unit."""
    return f"{value:,.{digits}f}" + (f" {unit}" if unit else "")


def duration_text(seconds: float) -> str:
    """A duration to 0.1 s, and from a minute on also as hours, minutes and seconds:
    ``4,093.2 s (1:08:13)``."""
    text = number_text(seconds, 1, "s")
    if abs(seconds) < 60 or not math.isfinite(seconds):
        return text
    whole = round(abs(seconds))
    hours, rest = divmod(whole, 3600)
    clock = (
        f"{hours}:{rest // 60:02d}:{rest % 60:02d}" if hours else f"{rest // 60}:{rest % 60:02d}"
    )
    return f"{text} ({'-' if seconds < 0 else ''}{clock})"


def moment_text(moment: dt.datetime) -> str:
    """A date and time in UTC to 0.1 s: ``2026-11-27 13:04:05.3 UTC``."""
    utc = moment.astimezone(dt.UTC)
    return f"{utc:%Y-%m-%d %H:%M:%S}.{utc.microsecond // 100_000} UTC"


def _display(
    field: str, description: str, text: Callable[[Any, Any], str | None]
) -> Callable[[Any, Any], str]:
    """A display method of a ModelAdmin or inline showing ``text(obj, value of field)``, the
    admin's empty value for None; sorted by the field in a list."""

    @admin.display(description=description, ordering=field)
    def show(model_admin: Any, obj: Any) -> str:
        value = getattr(obj, field)
        shown = None if value is None else text(obj, value)
        return model_admin.get_empty_value_display() if shown is None else shown

    return show


def rounded(field: str, *, digits: int, unit: str = "", description: str) -> Any:
    """A display method showing a float ``field`` rounded to ``digits`` decimals, with its
    unit: ``lat_shown = rounded("lat", digits=DEGREES, description="latitude")``."""
    return _display(field, description, lambda _, value: number_text(value, digits, unit))


def duration(field: str, *, description: str) -> Any:
    """A display method showing a duration in seconds to 0.1 s (``duration_text``)."""
    return _display(field, description, lambda _, value: duration_text(value))


def moment(
    field: str, *, description: str, to_datetime: Callable[[Any, float], dt.datetime | None]
) -> Any:
    """A display method showing a time on the platform clock, ``to_datetime(obj, value)`` as
    a date and time in UTC to 0.1 s."""

    def text(obj: Any, value: float) -> str | None:
        found = to_datetime(obj, value)
        return None if found is None else moment_text(found)

    return _display(field, description, text)


class PositionShown:
    """Display methods of a model's ``lat``, ``lng`` and ``alt`` fields (a ModelAdmin's or
    an inline's mixin): degrees to 6 decimals, altitude to 0.1 m."""

    lat_shown = rounded("lat", digits=DEGREES, description="latitude")
    lng_shown = rounded("lng", digits=DEGREES, description="longitude")
    alt_shown = rounded("alt", digits=METRES, unit="m", description="altitude")


# What the admin's sizes are entered in: binary units, as the quotas' defaults are (10 MB of
# storage is 10 * 1024 * 1024 bytes).
SIZE_UNITS = {"KB": 1024, "MB": 1024 * 1024}
_SHOWN_TO = Decimal("0.001")


class SizeField(forms.DecimalField):
    """A size kept in bytes, entered and shown in ``unit`` (``"MB"`` or ``"KB"``) to 3
    decimals; cleaned to whole bytes (an int), at least ``min_bytes``.

    A size that is no whole number of the unit (1,000,000 bytes: ``0.954`` MB) is shown
    rounded; the field counts as changed only when the number shown was changed, so saving a
    form that was not touched keeps every byte.
    """

    widget = AdminBigIntegerFieldWidget  # the admin's wide number box (step="any" added)

    def __init__(self, *, unit: str, min_bytes: int = 0, **kwargs: Any) -> None:
        self.unit = unit
        self.unit_bytes = SIZE_UNITS[unit]
        self.min_bytes = min_bytes
        super().__init__(**kwargs)

    def shown(self, size: int) -> str:
        """``size`` bytes in the field's unit: ``"10"``, ``"0.954"``."""
        units = (Decimal(size) / self.unit_bytes).quantize(_SHOWN_TO, rounding=ROUND_HALF_EVEN)
        return format(units.normalize(), "f")

    def prepare_value(self, value: Any) -> Any:
        # Bytes from the model; what a person typed (a string) is shown back as typed.
        return self.shown(value) if isinstance(value, int) else value

    def clean(self, value: Any) -> int | None:
        units = super().clean(value)
        if units is None:
            return None
        size = int((units * self.unit_bytes).to_integral_value(rounding=ROUND_HALF_EVEN))
        if size < self.min_bytes:
            raise ValidationError(f"At least {self.shown(self.min_bytes)} {self.unit}.")
        return size

    def has_changed(self, initial: Any, data: Any) -> bool:
        if self.disabled:
            return False
        try:
            entered = self.to_python(data)
        except ValidationError:
            return True
        before = None if initial in (None, "") else self.to_python(self.prepare_value(initial))
        return entered != before
