"""A small client of the CPCC REST API: token authentication, JSON, pagination, downloads.

Standard library only (urllib, json).
"""

from __future__ import annotations

import json
import re
import shutil
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Iterator, Mapping
from email.message import Message
from typing import IO, Any

USER_AGENT = "cpcc-client/1"


class ApiError(Exception):
    """The server answered with an HTTP error; ``body`` is its JSON (or text) answer."""

    def __init__(self, status: int, reason: str, body: Any, url: str) -> None:
        self.status = status
        self.reason = reason
        self.body = body
        self.url = url
        super().__init__(self.describe())

    def describe(self) -> str:
        """What the server said, for a person: its ``detail``, or each field's messages."""
        head = f"{self.status} {self.reason}"
        body = self.body
        if isinstance(body, Mapping):
            if set(body) == {"detail"}:
                return f"{head}: {body['detail']}"
            lines = [f"  {field}: {_flatten(messages)}" for field, messages in body.items()]
            return head + "\n" + "\n".join(lines)
        if isinstance(body, list):
            return f"{head}: {_flatten(body)}"
        text = str(body or "").strip()
        return f"{head}: {text[:500]}" if text else head


class Unreachable(Exception):
    """The server could not be reached at all."""

    def __init__(self, url: str, reason: object) -> None:
        self.url = url
        self.reason = reason
        super().__init__(f"cannot reach {url}: {reason}")


def _flatten(messages: Any) -> str:
    if isinstance(messages, list):
        return " ".join(_flatten(m) for m in messages)
    if isinstance(messages, Mapping):
        return "; ".join(f"{k}: {_flatten(v)}" for k, v in messages.items())
    return str(messages)


def _decode(raw: bytes, content_type: str | None) -> Any:
    if not raw:
        return None
    text = raw.decode("utf-8", errors="replace")
    if content_type and "json" in content_type:
        try:
            return json.loads(text)
        except ValueError:
            return text
    return text


class Client:
    """Talks to one CPCC server with one API token."""

    def __init__(self, base_url: str, token: str, *, timeout_s: float = 30.0) -> None:
        self.base_url = base_url.rstrip("/")
        self.token = token
        self.timeout_s = timeout_s

    def url(self, path: str, query: Mapping[str, str] | None = None) -> str:
        """The absolute URL of an API path such as ``/api/v1/vvs/``."""
        if path.startswith(("http://", "https://")):
            url = path
        else:
            url = self.base_url + "/" + path.lstrip("/")
        if query:
            url += ("&" if "?" in url else "?") + urllib.parse.urlencode(query)
        return url

    def _open(
        self, method: str, url: str, *, data: Any = None, timeout_s: float | None = None
    ) -> Any:
        headers = {
            "Authorization": f"Token {self.token}",
            "Accept": "application/json, */*;q=0.5",
            "User-Agent": USER_AGENT,
        }
        body = None
        if data is not None:
            body = json.dumps(data).encode("utf-8")
            headers["Content-Type"] = "application/json"
        request = urllib.request.Request(url, data=body, method=method, headers=headers)
        try:
            return urllib.request.urlopen(request, timeout=timeout_s or self.timeout_s)
        except urllib.error.HTTPError as exc:
            with exc:
                raw = exc.read()
                raise ApiError(
                    exc.code, exc.reason, _decode(raw, exc.headers.get("Content-Type")), url
                ) from None
        except urllib.error.URLError as exc:
            raise Unreachable(url, exc.reason) from None
        except OSError as exc:  # a timeout or a reset connection
            raise Unreachable(url, exc) from None

    def call(
        self,
        method: str,
        path: str,
        *,
        data: Any = None,
        query: Mapping[str, str] | None = None,
        timeout_s: float | None = None,
    ) -> Any:
        """One request; returns the decoded JSON answer. Raises ApiError or Unreachable.
        ``timeout_s``: for a request the server takes long to answer (a dry run)."""
        url = self.url(path, query)
        with self._open(method, url, data=data, timeout_s=timeout_s) as response:
            try:
                raw = response.read()
            except OSError as exc:
                raise Unreachable(url, exc) from None
            return _decode(raw, response.headers.get("Content-Type"))

    def pages(self, path: str, *, query: Mapping[str, str] | None = None) -> Iterator[Any]:
        """Every item of a paginated list, following the ``next`` links."""
        url: str | None = self.url(path, query)
        while url:
            page = self.call("GET", url)
            yield from page["results"]
            url = page.get("next")

    def download(self, path: str, out: IO[bytes], *, timeout_s: float = 600.0) -> str | None:
        """Copy a file the API serves into ``out``; returns the file name the server
        suggests (Content-Disposition), if any."""
        url = self.url(path)
        with self._open("GET", url, timeout_s=timeout_s) as response:
            try:
                shutil.copyfileobj(response, out)
            except OSError as exc:
                raise Unreachable(url, exc) from None
            return _filename(response.headers)


def _filename(headers: Message) -> str | None:
    disposition = headers.get("Content-Disposition") or ""
    match = re.search(r'filename="?([^";]+)"?', disposition)
    if not match:
        return None
    name = match.group(1).replace("/", "_").replace("\\", "_")
    return name if name not in ("", ".", "..") else None
