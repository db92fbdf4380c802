"""Who may ask the cockpit for what, in one place (module docstring of rig/web/server.py for the order).

- Host: without a token the server binds a loopback address, and answers only requests whose Host header
  names a loopback address with its port: a page elsewhere that re-points its own DNS name to 127.0.0.1
  (DNS rebinding) gets nothing.
- Token: any other address needs one. It is compared in constant time (hmac.compare_digest) and taken from
  an `Authorization: Bearer` header, from the cookie a first visit with `?token=` sets, or from that query.
- CSRF: an action (POST) must carry the page's token, a secret drawn at start-up that only pages of this
  server hold, and, when the browser names where the request comes from (Origin), this very origin.
- Paths: a request names a session as (folder index, file name). The name must be one path component
  (no separator, no `..`, not absolute, no NUL) and the file must resolve, symlinks followed, to a session
  file directly inside that folder. Nothing else on disk is opened because of a request.
- Escaping: `esc` for every string that reaches HTML, whatever its source.
"""

from __future__ import annotations

import hmac
import html
import ipaddress
from pathlib import Path

from rig.session.schema import looks_like_session

LOOPBACK_NAMES = ("localhost",)


class Refused(Exception):
    """A request the cockpit will not serve: HTTP status and one line for the client."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status
        self.message = message


def esc(value: object) -> str:
    """Text for HTML, in element content and in quoted attribute values alike."""
    return html.escape(str(value), quote=True)


def is_loopback(host: str) -> bool:
    if host.lower() in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def host_allowed(header: str | None, port: int) -> bool:
    """A Host header naming a loopback address (or `localhost`) with the server's port."""
    if not header:
        return False
    header = header.strip()
    name, sep, given_port = header.rpartition(":")
    if not sep or "]" in given_port:  # no port: only right for the default port
        name, given_port = header, "80"
    return given_port == str(port) and is_loopback(name)


def same_secret(given: str | None, secret: str) -> bool:
    """Constant-time comparison; a missing value never matches."""
    if given is None:
        return False
    return hmac.compare_digest(given.encode("utf-8", "surrogateescape"), secret.encode("utf-8"))


TOKEN_CHARS = frozenset("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-._~")
MIN_TOKEN_LENGTH = 16


def check_token(token: str) -> None:
    """A token must be long enough not to be guessed, and travel in a URL and a cookie unchanged."""
    from rig.core.errors import ConfigError

    if len(token) < MIN_TOKEN_LENGTH or not set(token) <= TOKEN_CHARS:
        raise ConfigError(f"--token / MAGRIG_TOKEN: use at least {MIN_TOKEN_LENGTH} characters of "
                          "A-Z a-z 0-9 - . _ ~ (for example: "
                          "python3 -c 'import secrets; print(secrets.token_urlsafe(24))')")


def check_name(name: str) -> None:
    """A session's file name as a request gives it: one plain path component."""
    if (not name or name in (".", "..") or "/" in name or "\\" in name or "\x00" in name
            or Path(name).is_absolute()):
        raise Refused(403, "not a file name in a served folder")


def session_file(roots: list[Path], root_index: str, name: str) -> Path:
    """The session file `name` directly inside folder number `root_index` of `roots` (see the module
    docstring); Refused otherwise."""
    if not root_index.isdigit() or int(root_index) >= len(roots):
        raise Refused(404, "no such folder")
    check_name(name)
    root = roots[int(root_index)].resolve()
    path = root / name
    try:
        resolved = path.resolve(strict=True)
    except (OSError, RuntimeError):
        raise Refused(404, "no such session") from None
    if resolved.parent != root:
        raise Refused(403, "outside the served folders")
    if not resolved.is_file() or not looks_like_session(resolved):
        raise Refused(404, "no such session")
    return resolved
