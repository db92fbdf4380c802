"""The cockpit's HTTP server: the standard library's ThreadingHTTPServer, one handler, a short route table.

    app = Cockpit(roots=[Path("sessions")], db_url=None, token=None)
    server = make_server(app, host="127.0.0.1", port=8765)   # refuses another host without a token
    server.serve_forever()

Routes (ROOT is the index of a served folder, NAME a session file's name in it, percent-encoded):

    GET  /                              sessions of every served folder
    GET  /fleet?station=&dut=&since=&until=&verdict=   the fleet database (with --db)
    GET  /s/ROOT/NAME                   a session: summary, acceptance, calibrations, downloads, events
    GET  /s/ROOT/NAME/live              its live view; /events is the live view's stream (server-sent
                                        events), /state the same state once, as JSON
    GET  /s/ROOT/NAME/report            its HTML report (rig report)
    GET  /s/ROOT/NAME/download?what=KIND&dut=D&model=M    calibration files, exports, samples CSV
    POST /s/ROOT/NAME/action            action=pause|abort: a request to the running campaign
    (rig/session/inbox.py) GET  /static/FILE                   the script, style sheet and icon

Every request passes, in this order: the Host check (without a token), the token (with one), the route;
an action also needs the CSRF token and a same-origin Origin. rig/web/guard.py holds the checks.
"""

from __future__ import annotations

import json
import logging
import math
import re
import secrets
import shutil
import tempfile
import urllib.parse
from dataclasses import dataclass, field
from http.cookies import CookieError, SimpleCookie
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from pathlib import Path

from rig.core.errors import ERRORS, MagrigError
from rig.web import guard, pages
from rig.web.downloads import CALIBRATION_KINDS, SAMPLES_KIND, Reports, calibration_download, samples_download
from rig.web.live import Cursor, Hub

log = logging.getLogger("magrig.web")

TOKEN_COOKIE = "magrig_token"
KEEPALIVE_S = 15.0
MAX_FORM_BYTES = 4096
PAGE_CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self'; connect-src 'self'; "
            "form-action 'self'; base-uri 'none'; frame-ancestors 'none'")
REPORT_REFRESH_S = 2  # how often a page of a report being built asks again (its Refresh header)
REPORT_CSP = ("default-src 'none'; style-src 'unsafe-inline'; img-src data:; base-uri 'none'; "
              "frame-ancestors 'none'")  # rig report's page: inline CSS, figures as data: URLs, no script
STATIC = {"cockpit.js": "text/javascript; charset=utf-8", "cockpit.css": "text/css; charset=utf-8",
          "favicon.svg": "image/svg+xml"}
SESSION_ROUTE = re.compile(r"^/s/([^/]+)/([^/]+)"
                           r"(/live|/events|/state|/report|/certificate|/download|/action|/[^/]+\.certificate\.html)?$")


@dataclass
class Cockpit:
    """What the server serves and its secrets."""

    roots: list[Path]
    db_url: str | None = None
    token: str | None = None
    csrf_token: str = field(default_factory=lambda: secrets.token_urlsafe(32))
    port: int = 0
    hub: Hub = field(default_factory=Hub)
    scratch: Path = field(default_factory=lambda: Path(tempfile.mkdtemp(prefix="magrig-cockpit-")))

    def __post_init__(self):
        self.roots = [Path(r) for r in self.roots]
        self.reports = Reports(self.scratch)
        folder = resources.files("rig.web").joinpath("static")
        self.static = {name: folder.joinpath(name).read_bytes() for name in STATIC}

    def close(self) -> None:
        self.hub.stop()
        shutil.rmtree(self.scratch, ignore_errors=True)


class CockpitServer(ThreadingHTTPServer):
    daemon_threads = True

    def __init__(self, app: Cockpit, address: tuple[str, int]):
        self.app = app
        super().__init__(address, Handler)
        app.port = self.server_address[1]

    def server_close(self) -> None:
        self.app.close()
        super().server_close()


def make_server(app: Cockpit, host: str = "127.0.0.1", port: int = 8765) -> CockpitServer:
    """Bind, or refuse in one line: another address than loopback needs a token."""
    if app.token is not None:
        guard.check_token(app.token)
    if not guard.is_loopback(host) and not app.token:
        raise MagrigError(f"--host {host}: the cockpit would answer other machines; give a token with "
                          "--token or MAGRIG_TOKEN (or keep the default 127.0.0.1)")
    try:
        return CockpitServer(app, (host, port))
    except OSError as exc:
        raise MagrigError(f"cannot listen on {host}:{port}: {exc.strerror or exc}") from None


class Handler(BaseHTTPRequestHandler):
    server: CockpitServer
    server_version = "magrig-cockpit"
    sys_version = ""
    timeout = 60

    @property
    def app(self) -> Cockpit:
        return self.server.app

    def log_message(self, format: str, *args) -> None:  # noqa: A002 - the base class's name
        log.info("%s %s", self.client_address[0], format % args)

    # --- entry points -----------------------------------------------------------------------------
    def do_GET(self) -> None:
        self._serve("GET")

    def do_POST(self) -> None:
        self._serve("POST")

    def _serve(self, method: str) -> None:
        try:
            self._route(method)
        except _Done:
            pass
        except guard.Refused as exc:
            self._page(exc.status, pages.error_page(self.app, exc.status, exc.message))
        except (BrokenPipeError, ConnectionResetError):
            pass
        except ERRORS as exc:  # a session or calibration the project's checks refuse: one line
            self._page(400, pages.error_page(self.app, 400, str(exc)))
        except Exception:
            log.exception("%s %s", method, self.path)
            try:
                self._page(500, pages.error_page(self.app, 500, "internal error (see the server's log)"))
            except OSError:
                pass

    def _route(self, method: str) -> None:
        if not self.path.startswith("/") or self.path.startswith("//"):
            raise guard.Refused(400, "not a path of this server")
        url = urllib.parse.urlsplit(self.path)
        query = {k: v[-1] for k, v in urllib.parse.parse_qs(url.query, max_num_fields=20).items()}
        self._check_access(url, query)
        path = url.path
        if method == "GET" and path == "/":
            return self._page(200, pages.sessions_page(self.app))
        if method == "GET" and path == "/fleet":
            if not self.app.db_url:
                raise guard.Refused(404, "no fleet database: start rig serve with --db URL")
            return self._page(200, pages.fleet_page(self.app, query))
        if method == "GET" and path.startswith("/static/"):
            return self._static(path.removeprefix("/static/"))
        match = SESSION_ROUTE.match(path)
        if match is None:
            raise guard.Refused(404, "no such page")
        try:
            name = urllib.parse.unquote(match.group(2), errors="strict")
        except UnicodeDecodeError:
            raise guard.Refused(400, "not a file name") from None
        root, tail = match.group(1), match.group(3)
        ref = pages.SessionRef(int(root) if root.isdigit() else -1, name,
                               guard.session_file(self.app.roots, root, name))
        if method == "POST":
            if tail != "/action":
                raise guard.Refused(405, "only actions are posted")
            return self._action(ref)
        if tail is None:
            return self._page(200, pages.session_page(self.app, ref))
        if tail == "/live":
            return self._page(200, pages.live_page(self.app, ref))
        if tail == "/events":
            return self._events(ref)
        if tail == "/state":
            return self._state(ref)
        if tail == "/report":
            got = self.app.reports.html(ref.path)
            if isinstance(got, str):  # still being built: how far, and the browser asks again
                return self._send(200, pages.report_building_page(self.app, ref, got).encode("utf-8"),
                                  "text/html; charset=utf-8", extra={"Refresh": str(REPORT_REFRESH_S)})
            return self._send(200, got, "text/html; charset=utf-8", csp=REPORT_CSP)
        if tail == "/certificate":
            return self._certificate(ref, query.get("dut", ""))
        if tail.endswith(".certificate.html"):  # the report's link: <session stem>.<dut>.certificate.html
            stem = name.removesuffix(".session") + "."
            file = urllib.parse.unquote(tail[1:])
            if not file.startswith(stem):
                raise guard.Refused(404, "no such certificate")
            return self._certificate(ref, file[len(stem):].removesuffix(".certificate.html"))
        if tail == "/download":
            return self._download(ref, query)
        raise guard.Refused(405, "use POST for actions")

    def _certificate(self, ref: pages.SessionRef, dut: str) -> None:
        """A DUT's calibration certificate (rig/report/certificate.py), made from the session as it is."""
        from rig.core.errors import ERRORS
        from rig.report.certificate import certificate_html

        try:
            page = certificate_html(ref.path, dut)
        except ERRORS as exc:
            raise guard.Refused(404, str(exc)) from None
        self._send(200, page.encode(), "text/html; charset=utf-8", csp=REPORT_CSP)

    # --- access -----------------------------------------------------------------------------------
    def _check_access(self, url, query: dict[str, str]) -> None:
        app = self.app
        if not app.token:
            if not guard.host_allowed(self.headers.get("Host"), app.port):
                raise guard.Refused(421, "this server answers only to its loopback address")
            return
        if guard.same_secret(query.get("token"), app.token):  # first visit: keep it in a cookie
            clean = urllib.parse.urlencode({k: v for k, v in query.items() if k != "token"})
            self.send_response(303)
            self.send_header("Location", url.path + (f"?{clean}" if clean else ""))
            self.send_header("Set-Cookie", f"{TOKEN_COOKIE}={app.token}; HttpOnly; SameSite=Strict; Path=/")
            self._common_headers(PAGE_CSP)
            self.send_header("Content-Length", "0")
            self.end_headers()
            raise _Done()
        bearer = self.headers.get("Authorization", "")
        given = bearer.removeprefix("Bearer ").strip() if bearer.startswith("Bearer ") else self._cookie()
        if not guard.same_secret(given, app.token):
            raise guard.Refused(401, "token needed: open this address with ?token=YOUR_TOKEN once")

    def _cookie(self) -> str | None:
        try:
            cookie = SimpleCookie(self.headers.get("Cookie", ""))
        except CookieError:
            return None
        morsel = cookie.get(TOKEN_COOKIE)
        return None if morsel is None else morsel.value

    def _action(self, ref: pages.SessionRef) -> None:
        from rig.session.inbox import post

        form = self._form()
        if not guard.same_secret(form.get("csrf"), self.app.csrf_token):
            raise guard.Refused(403, "the page's token is missing or stale: reload the page")
        origin = self.headers.get("Origin")
        if origin is not None and origin != f"http://{self.headers.get('Host', '')}":
            raise guard.Refused(403, f"a request from another site ({origin}) is refused")
        if form.get("confirm") != "yes":
            raise guard.Refused(400, "an action must be confirmed")
        action = form.get("action", "")
        if action not in ("pause", "abort"):
            raise guard.Refused(400, "unknown action")
        request = post(ref.path, action, source=f"web client {self.client_address[0]}")
        body = {"ok": True, "action": action, "id": request.id,
                "message": f"{action} requested: the run takes it at its next safe point"}
        self._send(202, json.dumps(body).encode(), "application/json")

    def _form(self) -> dict[str, str]:
        if self.headers.get_content_type() != "application/x-www-form-urlencoded":
            raise guard.Refused(415, "an action is a form post")
        try:
            length = int(self.headers.get("Content-Length", ""))
        except ValueError:
            raise guard.Refused(411, "Content-Length needed") from None
        if not 0 <= length <= MAX_FORM_BYTES:
            raise guard.Refused(413, "form too large")
        text = self.rfile.read(length).decode("utf-8", "replace")
        return {k: v[-1] for k, v in urllib.parse.parse_qs(text, max_num_fields=10).items()}

    # --- bodies -----------------------------------------------------------------------------------
    def _static(self, name: str) -> None:
        if name not in STATIC:
            raise guard.Refused(404, "no such file")
        self._send(200, self.app.static[name], STATIC[name], cache="max-age=60")

    def _download(self, ref: pages.SessionRef, query: dict[str, str]) -> None:
        what, dut, model = query.get("what", ""), query.get("dut", ""), query.get("model", "")
        if what == SAMPLES_KIND:
            found = samples_download(ref.path, dut)
        elif what in CALIBRATION_KINDS:
            found = calibration_download(ref.path, what, dut, model, self.app.scratch)
        else:
            raise guard.Refused(404, "no such download")
        disposition = f'attachment; filename="{found.filename}"'
        self._send(200, found.body, found.content_type, extra={"Content-Disposition": disposition})

    def _state(self, ref: pages.SessionRef) -> None:
        live = self.app.hub.subscribe(ref.path)
        try:
            body = json.dumps(_nulls(live.message(Cursor())), default=str).encode()
        finally:
            self.app.hub.unsubscribe(live)
        self._send(200, body, "application/json")

    def _events(self, ref: pages.SessionRef) -> None:
        """Server-sent events: the whole state first, then what is new as soon as the file shows it."""
        hub = self.app.hub
        live = hub.subscribe(ref.path)
        try:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self._common_headers(PAGE_CSP)
            self.end_headers()
            cursor = Cursor()
            self._event(live.message(cursor))
            while not hub.stopping.is_set():
                if live.wait(cursor, KEEPALIVE_S, hub.stopping):
                    self._event(live.message(cursor))
                else:
                    self.wfile.write(b": keep-alive\n\n")
        finally:
            hub.unsubscribe(live)
            self.close_connection = True

    def _event(self, message: dict) -> None:
        data = json.dumps(_nulls(message), default=str)
        self.wfile.write(b"event: state\ndata: " + data.encode() + b"\n\n")
        self.wfile.flush()

    # --- sending ----------------------------------------------------------------------------------
    def _page(self, status: int, html: str) -> None:
        self._send(status, html.encode("utf-8"), "text/html; charset=utf-8")

    def _send(self, status: int, body: bytes, content_type: str, *, csp: str = PAGE_CSP,
              cache: str = "no-store", extra: dict[str, str] | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", cache)
        for key, value in (extra or {}).items():
            self.send_header(key, value)
        self._common_headers(csp)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _common_headers(self, csp: str) -> None:
        self.send_header("Content-Security-Policy", csp)
        self.send_header("X-Content-Type-Options", "nosniff")
        self.send_header("X-Frame-Options", "DENY")
        self.send_header("Referrer-Policy", "no-referrer")


class _Done(Exception):
    """The response is already sent (a redirect)."""


def _nulls(value):
    """NaN and infinities as null: JSON has no spelling for them, and a browser refuses NaN."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _nulls(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_nulls(v) for v in value]
    return value


def serve(app: Cockpit, host: str, port: int, *, ready=None) -> None:
    """Run until Ctrl-C (or `server.shutdown()` from another thread); `ready(server)` sees it bound."""
    server = make_server(app, host, port)
    if ready is not None:
        ready(server)
    try:
        server.serve_forever(poll_interval=0.5)
    except KeyboardInterrupt:
        pass
    finally:
        server.server_close()
