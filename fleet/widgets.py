"""The admin's operation-area widget: a Leaflet map to draw and edit an RV's area polygon."""

from __future__ import annotations

from typing import Any

from django import forms
from django.conf import settings
from django.template.loader import render_to_string
from django.utils.safestring import SafeString


def map_media(*, css: tuple[str, ...] = (), js: tuple[str, ...] = ()) -> forms.Media:
    """What an admin map needs (the area widget, the fleet overview): Leaflet, served by the
    platform (static/vendor/), the helpers and styles the admin's maps share, then ``css`` and
    ``js``, in this order (Media puts the files of one list in the order given)."""
    return forms.Media(
        css={"all": ["vendor/leaflet/leaflet.css", *css, "css/admin-map.css"]},
        js=["vendor/leaflet/leaflet.js", "js/admin/map-common.js", *js],
    )


class AreaWidget(forms.Textarea):
    """The area's JSON text (a closed ring of ``[lat, lng]``) under a map that draws it.

    ``static/js/admin/area-widget.js`` draws the polygon and lets the operator draw, reshape,
    drag or delete it (Leaflet-Geoman), writing the ring back into the textarea, which stays
    editable; the form is validated and saved as before. ``others`` (``{name, status, area}``
    of the other RVs) and ``stations`` (``{name, lat, lng}``) are drawn for orientation, on the
    tiles ``CPCC_MAP_TILES`` names, or else on the platform's own tiles of the simulated world
    (fleet/views.py).
    """

    map_template_name = "admin/fleet/vehicle/area_widget.html"

    @property
    def media(self) -> forms.Media:
        return map_media(
            css=("vendor/leaflet-geoman/leaflet-geoman.css",),
            js=("vendor/leaflet-geoman/leaflet-geoman.min.js", "js/admin/area-widget.js"),
        )

    def __init__(
        self,
        *,
        others: list[dict[str, Any]] | None = None,
        stations: list[dict[str, Any]] | None = None,
        attrs: dict[str, Any] | None = None,
    ) -> None:
        super().__init__(attrs={"rows": 4, "cols": 80, "class": "cpcc-area-json", **(attrs or {})})
        self.others = others or []
        self.stations = stations or []

    def render(
        self, name: str, value: Any, attrs: dict[str, Any] | None = None, renderer: Any = None
    ) -> SafeString:
        # The textarea through the form's renderer as usual; the map around it from the
        # project's templates (the default form renderer does not read templates/).
        textarea = super().render(name, value, attrs, renderer)
        input_id = (attrs or {}).get("id") or self.attrs.get("id") or f"id_{name}"
        return render_to_string(
            self.map_template_name,
            {
                "textarea": textarea,
                "input_id": input_id,
                "context_id": f"{input_id}_context",
                "tiles": settings.CPCC_MAP_TILES,
                "context": {"others": self.others, "stations": self.stations},
            },
        )
