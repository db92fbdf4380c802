"""`rig serve` over real HTTP on 127.0.0.1: every refusal the cockpit promises (Host, token, CSRF, paths
out of the served folders, escaping), and downloads equal to what the CLI commands write."""

from __future__ import annotations

import http.client
import json
import os
import threading
import time
import urllib.parse
from pathlib import Path
from types import SimpleNamespace

import pytest

from drivers.clock import SimClock
from rig.cli import main
from rig.config.loading import load_campaign
from rig.core.errors import ConfigError, MagrigError
from rig.run.campaign import run_campaign
from rig.session.events import Kind, Reason
from rig.session.inbox import request_path
from rig.session.rows import SampleRow, TemperatureRow
from rig.session.writer import Session
from rig.web.server import Cockpit, make_server
from tests.system.campaign_helpers import SIM_STATION, small_plan

pytestmark = pytest.mark.system

SECRET = "OUTSIDE-SECRET-7f3a"
HOSTILE = '<script>alert("x")</script>"><img src=x onerror=alert(1)>'
TOKEN = "test-token-0123456789abcdef"


def tiny_session(path: Path, *, plan_name: str = "tiny", station_name: str = "bench", dut: str = "dut1",
                 message: str = "started") -> Path:
    points = [SimpleNamespace(id="T01-F01", index=0, temp_index=1, setpoint_c=25.0, field_index=1,
                              target={"field_nt": [50000.0, 0.0, 0.0]})]
    with Session.create(path, plan_text="name: x\n", station_text="name: y\n", plan_name=plan_name,
                        station_name=station_name, points=points, simulated={"chamber": True},
                        clock=SimClock()) as s:
        s.record_point("T01-F01", [SampleRow(dut, 1.0, (1.0, 2.0, 3.0), (1.0, 2.0, 3.0), 25.0)],
                       temperatures=[TemperatureRow(1.0, 25.0, None, 25.1, {dut: 25.0})])
        s.log_event(Kind.HOLD, message, code=Reason.DEVICE_FAULT, point_id="T01-F01", device=dut)
    return path


@pytest.fixture(scope="module")
def folders(tmp_path_factory):
    """A served folder with a real campaign's session, a hostile one, a non-session file and symlinks
    pointing out; beside it, a folder that must never be served."""
    base = tmp_path_factory.mktemp("cockpit")
    root, outside = base / "sessions", base / "outside"
    root.mkdir()
    outside.mkdir()
    campaign = load_campaign(small_plan(base, samples=3), SIM_STATION)
    outcome = run_campaign(campaign=campaign, session_path=root / "run.session")
    assert outcome.result.status == "completed"
    tiny_session(root / "hostile.session", plan_name=HOSTILE, station_name=HOSTILE, dut="<b>dut</b>",
                 message=HOSTILE)
    tiny_session(outside / "secret.session", plan_name=SECRET, station_name=SECRET)
    (outside / "secret.txt").write_text(SECRET)
    (root / "notes.txt").write_text("not a session")
    (root / "link.session").symlink_to(outside / "secret.session")
    (root / "passwd.session").symlink_to("/etc/passwd")
    (root / "txt.session").symlink_to(outside / "secret.txt")
    return SimpleNamespace(base=base, root=root, outside=outside)


def start(app: Cockpit):
    server = make_server(app, "127.0.0.1", 0)
    threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True).start()
    return server


@pytest.fixture
def server(folders):
    srv = start(Cockpit(roots=[folders.root]))
    yield srv
    srv.shutdown()
    srv.server_close()


@pytest.fixture
def token_server(folders):
    srv = start(Cockpit(roots=[folders.root], token=TOKEN))
    yield srv
    srv.shutdown()
    srv.server_close()


def request(srv, method: str, path: str, *, headers: dict | None = None, body: str | None = None):
    """Exactly this request line and these headers (http.client neither normalises nor quotes)."""
    conn = http.client.HTTPConnection("127.0.0.1", srv.server_address[1], timeout=30)
    hdrs = {"Host": f"127.0.0.1:{srv.server_address[1]}", **(headers or {})}
    conn.putrequest(method, path, skip_host=True, skip_accept_encoding=True)
    for k, v in hdrs.items():
        if v is not None:
            conn.putheader(k, v)
    data = body.encode() if body is not None else None
    if data is not None:
        conn.putheader("Content-Length", str(len(data)))
    conn.endheaders(data)
    resp = conn.getresponse()
    raw = resp.read()
    out = SimpleNamespace(status=resp.status, headers=resp.headers, raw=raw,
                          body=raw.decode("utf-8", "replace"))
    conn.close()
    return out


# --- Host and token ---------------------------------------------------------------------------------
def test_without_a_token_only_loopback_names_of_this_port_are_answered(server):
    port = server.server_address[1]
    for host in (f"127.0.0.1:{port}", f"localhost:{port}", f"[::1]:{port}"):
        assert request(server, "GET", "/", headers={"Host": host}).status == 200
    for host in ("evil.example", f"evil.example:{port}", f"127.0.0.1:{port + 1}", f"10.0.0.1:{port}", None):
        got = request(server, "GET", "/", headers={"Host": host})
        assert got.status == 421 and "run.session" not in got.body, host


def test_another_address_needs_a_token_and_a_token_must_be_strong(folders):
    with pytest.raises(MagrigError, match="--host 192.0.2.1: .*give a token"):
        make_server(Cockpit(roots=[folders.root]), "192.0.2.1", 0)  # refused before anything binds
    for weak in ("short", "has spaces in it ok?", "semi;colon-token-0123456789"):
        with pytest.raises(ConfigError, match="at least 16 characters"):
            make_server(Cockpit(roots=[folders.root], token=weak), "127.0.0.1", 0)


def test_with_a_token_every_request_needs_it(token_server):
    srv = token_server
    for headers in ({}, {"Authorization": "Bearer wrong-token-0123456789"}, {"Cookie": "magrig_token=nope"},
                    {"Authorization": f"Basic {TOKEN}"}, {"Cookie": 'magrig_token="x'}):
        got = request(srv, "GET", "/", headers=headers)
        assert got.status == 401 and "run.session" not in got.body, headers
    assert request(srv, "GET", "/?token=wrong-token-0123456789").status == 401
    assert request(srv, "GET", "/static/cockpit.js").status == 401  # even the script
    assert request(srv, "GET", "/", headers={"Authorization": f"Bearer {TOKEN}"}).status == 200
    first = request(srv, "GET", f"/fleet?token={TOKEN}&station=a", headers={"Host": "rig-pc.lab:1"})
    assert first.status == 303 and first.headers["Location"] == "/fleet?station=a"
    cookie = first.headers["Set-Cookie"]
    assert cookie.startswith(f"magrig_token={TOKEN};")
    assert "HttpOnly" in cookie and "SameSite=Strict" in cookie
    assert request(srv, "GET", "/", headers={"Cookie": f"magrig_token={TOKEN}"}).status == 200


# --- actions ----------------------------------------------------------------------------------------------
def test_actions_are_confirmed_same_origin_posts_with_the_pages_token(server, folders):
    session = folders.root / "run.session"
    lock = Path(f"{session}.lock")
    lock.write_text(f"{os.getpid()}\n")  # the campaign is "running": this process holds its lock
    port = server.server_address[1]
    csrf = server.app.csrf_token
    form = {"action": "pause", "confirm": "yes", "csrf": csrf}
    url = "/s/0/run.session/action"
    plain = {"Content-Type": "application/x-www-form-urlencoded"}
    try:
        refused = [
            ("GET", {}, None, 405),
            ("POST", plain, {**form, "csrf": ""}, 403),
            ("POST", plain, {k: v for k, v in form.items() if k != "csrf"}, 403),
            ("POST", plain, {**form, "csrf": csrf[:-1] + ("A" if csrf[-1] != "A" else "B")}, 403),
            ("POST", {**plain, "Origin": "http://evil.example"}, form, 403),
            ("POST", {**plain, "Origin": f"http://localhost:{port + 1}"}, form, 403),
            ("POST", {"Content-Type": "text/plain"}, form, 415),
            ("POST", {"Content-Type": "application/json"}, form, 415),
            ("POST", plain, {**form, "confirm": "no"}, 400),
            ("POST", plain, {**form, "action": "shutdown"}, 400),
        ]
        for method, headers, data, status in refused:
            body = None if data is None else urllib.parse.urlencode(data)
            got = request(server, method, url, headers=headers, body=body)
            assert got.status == status, (method, headers, data, got.body)
            assert not request_path(session).exists()
        ok = request(server, "POST", url, headers={**plain, "Origin": f"http://127.0.0.1:{port}"},
                     body=urllib.parse.urlencode(form))
        assert ok.status == 202 and json.loads(ok.body)["action"] == "pause"
        sent = json.loads(request_path(session).read_text())
        assert sent["source"] == "web client 127.0.0.1" and sent["pid"] == os.getpid()
    finally:
        request_path(session).unlink(missing_ok=True)
        lock.unlink()
    stopped = request(server, "POST", url, headers=plain, body=urllib.parse.urlencode(form))
    assert stopped.status == 400 and "no run is running this session" in stopped.body


# --- paths ----------------------------------------------------------------------------------------------
ESCAPES = [
    "/s/0/..", "/s/0/%2e%2e", "/s/0/.%2e", "/s/0/..%2F..%2Fetc%2Fpasswd",
    "/s/0/..%2foutside%2fsecret.session",
    "/s/0/%2E%2E%2Foutside%2Fsecret.txt", "/s/0/..%5C..%5Coutside%5Csecret.session",
    "/s/0/%252e%252e%252foutside%252fsecret.session", "/s/0/%2Fetc%2Fpasswd",
    "/s/0/%2F{outside}%2Fsecret.session", "/s/0/link.session", "/s/0/link.session/live",
    "/s/0/link.session/state", "/s/0/link.session/report",
    "/s/0/link.session/download?what=samples-csv&dut=dut1",
    "/s/0/passwd.session", "/s/0/txt.session", "/s/0/notes.txt", "/s/0/secret.session%00.txt",
    "/s/1/secret.session", "/s/-1/run.session", "/s/0/../../outside/secret.session", "/../outside/secret.txt",
    "/static/..%2Fserver.py", "/static/../server.py", "/static/%2e%2e%2fguard.py", "/static//etc/passwd",
    "//evil.example/", "/s/0/%ff%fe",
]


def test_nothing_outside_the_served_folders_is_ever_served(server, folders):
    for raw in ESCAPES:
        path = raw.replace("{outside}", urllib.parse.quote(str(folders.outside).strip("/"), safe=""))
        got = request(server, "GET", path)
        assert got.status in (400, 403, 404, 405), (path, got.status)
        assert SECRET not in got.body and "root:" not in got.body, path
    listing = request(server, "GET", "/")
    assert "run.session" in listing.body and "hostile.session" in listing.body
    assert "link.session" not in listing.body and SECRET not in listing.body  # not listed, not read


def test_every_string_from_a_session_is_escaped(server):
    raw = [HOSTILE, "<script>", "<img", "<b>dut</b>"]
    for path in ("/", "/s/0/hostile.session", "/s/0/hostile.session/live"):
        got = request(server, "GET", path)
        assert got.status == 200, path
        assert not any(r in got.body for r in raw), path
    page = request(server, "GET", "/s/0/hostile.session").body
    assert ("&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;&quot;&gt;"
            "&lt;img src=x onerror=alert(1)&gt;") in page
    assert "&lt;b&gt;dut&lt;/b&gt;" in page
    state = request(server, "GET", "/s/0/hostile.session/state")
    assert state.headers["Content-Type"] == "application/json"
    assert json.loads(state.body)["summary"]["plan"] == HOSTILE  # data for textContent, never markup
    for path in ("/", "/s/0/hostile.session/live", "/s/0/run.session/report", "/static/cockpit.js"):
        headers = request(server, "GET", path).headers
        assert "script-src" not in headers["Content-Security-Policy"] or "'self'" in headers[
            "Content-Security-Policy"]
        assert "unsafe-eval" not in headers["Content-Security-Policy"]
        assert headers["X-Content-Type-Options"] == "nosniff" and headers["X-Frame-Options"] == "DENY"


# --- what is served ------------------------------------------------------------------------------------
def test_downloads_are_what_the_cli_commands_write(server, folders, tmp_path, capsys):
    session = folders.root / "run.session"
    got = request(server, "GET", "/s/0/run.session/download?what=cal-yaml&dut=mmc0&model=t24")
    assert got.status == 200
    assert got.headers["Content-Disposition"] == 'attachment; filename="run.mmc0.t24.yaml"'
    assert got.raw == (folders.root / "run.mmc0.t24.yaml").read_bytes()  # as the run wrote it beside it
    for kind, fmt in (("c-header", "c-header"), ("flight-json", "json"), ("params-csv", "csv")):
        assert main(["export-cal", str(folders.root / "run.mmc0.t24.yaml"), "--format", fmt, "--name", "mmc0",
                     "-o", str(tmp_path / f"cli.{fmt}")]) == 0
        web = request(server, "GET", f"/s/0/run.session/download?what={kind}&dut=mmc0&model=t24")
        assert web.status == 200 and web.raw == (tmp_path / f"cli.{fmt}").read_bytes(), kind
    assert main(["export", str(session), "--csv", "--dut", "serial0", "-o", str(tmp_path / "cli.csv")]) == 0
    web = request(server, "GET", "/s/0/run.session/download?what=samples-csv&dut=serial0")
    assert web.status == 200 and web.raw == (tmp_path / "cli.csv").read_bytes()
    capsys.readouterr()
    for query in ("what=cal-yaml&dut=nobody&model=t24", "what=samples-csv&dut=..%2F..%2Fetc", "what=../x"):
        bad = request(server, "GET", f"/s/0/run.session/download?{query}")
        assert bad.status in (400, 404) and "Traceback" not in bad.body, query


def test_session_report_and_live_pages(server):
    page = request(server, "GET", "/s/0/run.session")
    assert page.status == 200
    for text in ("Calibrations", "run.mmc0.t24.yaml".split(".")[1], "completed", "Events"):
        assert text in page.body
    report = report_when_built(server, "/s/0/run.session/report")
    assert report.status == 200 and "<h2>Summary</h2>" in report.body
    assert "script-src" not in report.headers["Content-Security-Policy"]  # a report needs no script
    state = json.loads(request(server, "GET", "/s/0/run.session/state").body)
    assert state["summary"]["progress"]["done"] == state["summary"]["progress"]["planned"] == 12
    assert state["summary"]["run"]["state"] == "completed" and state["telemetry"]
    assert {d["name"] for d in state["summary"]["duts"]} == {"mmc0", "serial0"}


def report_when_built(srv, path: str, timeout_s: float = 120.0):
    """The report at `path`, asked again while the server answers that it is still being built (a loaded
    machine may take longer than the server's wait even for a small session)."""
    deadline = time.monotonic() + timeout_s
    got = request(srv, "GET", path)
    while "Refresh" in got.headers and time.monotonic() < deadline:
        time.sleep(0.2)
        got = request(srv, "GET", path)
    return got


def test_a_report_still_being_built_answers_with_its_progress_and_then_comes(folders, tmp_path):
    """A report that takes longer than the request's wait (a 64-DUT session: most of a minute) answers with
    how far it is and a Refresh header; asked again, the report itself comes, and then at once. A build
    that fails says why once, as one line, and the next request builds again."""
    app = Cockpit(roots=[folders.root, tmp_path])
    app.reports.wait_s = 0.0  # every build outlasts the wait
    srv = start(app)
    try:
        first = request(srv, "GET", "/s/0/run.session/report")
        assert first.status == 200 and first.headers["Refresh"] == "2"
        assert "Building the report: " in first.body and "script-src 'self'" in first.headers[
            "Content-Security-Policy"]
        got = report_when_built(srv, "/s/0/run.session/report")
        assert got.status == 200 and "<h2>Summary</h2>" in got.body and "Refresh" not in got.headers
        again = request(srv, "GET", "/s/0/run.session/report")
        assert again.body == got.body
        with Session.create(tmp_path / "empty.session", plan_text="name: x\n", station_text="name: y\n",
                            plan_name="x", station_name="y", points=[], simulated={}, clock=SimClock()):
            pass
        app.reports.wait_s = 60.0
        failed = request(srv, "GET", "/s/1/empty.session/report")
        assert failed.status == 400 and "holds no samples yet" in failed.body
        assert "Traceback" not in failed.body
        assert request(srv, "GET", "/s/1/empty.session/report").status == 400  # built again, the same answer
    finally:
        srv.shutdown()
        srv.server_close()


# --- fleet ------------------------------------------------------------------------------------------------
def test_the_fleet_page_lists_and_filters_as_rig_fleet_list_does(fleet_db, tmp_path, capsys):
    import datetime as dt

    from rig.fleet.push import push_snapshot
    from rig.fleet.schema import connect
    from rig.fleet.source import session_snapshot
    from tests.fleet_sessions import Spec, write_session

    specs = {"a": ("rig-a", None, 2), "b": ("rig-a", "FAIL", 3), "c": ("<i>rig-b</i>", "PASS", 4)}
    with connect(fleet_db) as conn:
        for seed, (name, (station, verdict, day)) in enumerate(specs.items(), start=1):
            path = write_session(tmp_path / f"{name}.session",
                                 Spec(seed=seed, station=station, day=dt.date(2026, 3, day)))
            if verdict:
                with Session.open(path) as s:
                    s.record_acceptance([{"dut": "dut1", "model": "t24", "passed": int(verdict == "PASS"),
                                          "verdict": verdict, "failed": "", "heldout_rms_nt": 1.0,
                                          "fit_rms_nt": 1.0, "lag_s": None, "notes": ""}])
            push_snapshot(conn, session_snapshot(path))
    srv = start(Cockpit(roots=[tmp_path], db_url=fleet_db))
    try:
        def listed(query: str) -> list[str]:
            got = request(srv, "GET", f"/fleet{query}")
            assert got.status == 200 and "<i>" not in got.body
            return sorted(n for n in specs if f"{n}.session" in got.body)

        assert listed("") == ["a", "b", "c"]
        page = request(srv, "GET", "/fleet").body
        assert "&lt;i&gt;rig-b&lt;/i&gt;" in page and '<svg class="verdicts"' in page
        assert listed("?station=rig-a") == ["a", "b"]
        assert listed("?verdict=fail") == ["b"]
        assert listed("?since=2026-03-03&until=2026-03-04") == ["b"]
        assert listed("?dut=dut1&verdict=PASS") == ["c"]
        for query, complaint in (("?since=yesterday", "since: &#x27;yesterday&#x27; is not a date"),
                                 ("?verdict=MAYBE", "verdict: &#x27;MAYBE&#x27; is not PASS or FAIL")):
            got = request(srv, "GET", f"/fleet{query}")
            assert got.status == 200 and complaint in got.body and "Traceback" not in got.body
        assert main(["fleet", "list", "--db", fleet_db, "--station", "rig-a"]) == 0
        cli = capsys.readouterr().out  # the CLI's listing holds the same sessions
        assert "a.session" in cli and "b.session" in cli and "c.session" not in cli
    finally:
        srv.shutdown()
        srv.server_close()
    no_db = start(Cockpit(roots=[tmp_path]))
    try:
        assert request(no_db, "GET", "/fleet").status == 404
    finally:
        no_db.shutdown()
        no_db.server_close()
