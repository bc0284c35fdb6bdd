"""Where ``cpcc login`` keeps API tokens: one per platform address, in
``$XDG_CONFIG_HOME/cpcc/credentials.json`` (``~/.config/cpcc/`` by default), readable by the
user only. ``CPCC_TOKEN``, when set, wins over what is kept here."""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path


def credentials_path() -> Path:
    """The file the tokens are kept in."""
    base = os.environ.get("XDG_CONFIG_HOME", "").strip() or str(Path.home() / ".config")
    return Path(base) / "cpcc" / "credentials.json"


def _site(url: str) -> str:
    return url.strip().rstrip("/")


def _read() -> dict[str, str]:
    try:
        data = json.loads(credentials_path().read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    if not isinstance(data, dict):
        return {}
    return {str(site): str(token) for site, token in data.items() if isinstance(token, str)}


def _write(tokens: dict[str, str]) -> None:
    """Replace the file at once (a new file, then renamed), made readable by the user only
    before anything is written into it."""
    path = credentials_path()
    path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
    handle, name = tempfile.mkstemp(dir=path.parent, prefix=".credentials-", suffix=".part")
    try:
        os.fchmod(handle, 0o600)
        with os.fdopen(handle, "w", encoding="utf-8") as out:
            json.dump(tokens, out, indent=2, sort_keys=True)
            out.write("\n")
        os.replace(name, path)
    except BaseException:
        Path(name).unlink(missing_ok=True)
        raise


def stored_token(url: str) -> str | None:
    """The token kept for this platform address, if any."""
    return _read().get(_site(url))


def store_token(url: str, token: str) -> Path:
    """Keep the token for this platform address; returns the file."""
    tokens = _read()
    tokens[_site(url)] = token
    _write(tokens)
    return credentials_path()


def forget_token(url: str) -> bool:
    """Drop the token kept for this platform address; False when there was none."""
    tokens = _read()
    if tokens.pop(_site(url), None) is None:
        return False
    _write(tokens)
    return True
