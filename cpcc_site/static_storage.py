"""The static files as production serves them: WhiteNoise's compressed copies under names with
a hash of their content, and the references between files rewritten to those names.

Django's post-processing rewrites every ``url(...)`` of a stylesheet it takes for a file. Inside
an inline SVG icon (a ``data:image/svg+xml`` URL, as in Leaflet-Geoman's stylesheet), a
gradient or a mask is referred to as ``url(%23id)``, the ``#`` percent-encoded: Django took it
for a file and wrote ``url("#id#id")`` into the icon, which broke the SVG (the area editor's
toolbar showed empty buttons). Such a reference is left as it is.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from typing import Any

from whitenoise.storage import CompressedManifestStaticFilesStorage


class HashedStaticFiles(CompressedManifestStaticFilesStorage):
    def url_converter(
        self, name: str, hashed_files: dict[str, Any], template: str | None = None
    ) -> Callable[[re.Match[str]], str]:
        convert = super().url_converter(name, hashed_files, template)

        def converter(matched: re.Match[str]) -> str:
            if matched.group("url").startswith("%23"):  # a fragment of the same document
                return matched.group("matched")
            return convert(matched)

        return converter
