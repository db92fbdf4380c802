"""The cockpit's HTML pages. Every string from a session, a station or the fleet database goes through
`esc`; the pages hold no script of their own (rig/web/static/cockpit.js does the live part) and load
nothing from elsewhere.

    sessions_page(app)                  the sessions of every served folder, as `rig sessions` lists them
    session_page(app, ref)              one session: summary, acceptance, calibrations, downloads, events;
                                        while it runs, also the live view's progress, plot and DUTs, all
                                        kept moving by the live view's own stream (cockpit.js)
    live_page(app, ref)                 the live view's frame (cockpit.js fills it from the event stream)
    fleet_page(app, query)              the fleet database: rigs, verdicts over time, sessions
    error_page(app, status, message)
"""

from __future__ import annotations

import datetime as dt
import json
import urllib.parse
from dataclasses import dataclass
from pathlib import Path

from rig.core.errors import ERRORS
from rig.session.inbox import running_pid
from rig.web.guard import Refused, esc, session_file

MAX_EVENTS_SHOWN = 200


@dataclass(frozen=True)
class SessionRef:
    """A served session: its folder's index, its file name there and its resolved path."""

    root: int
    name: str
    path: Path

    def url(self, tail: str = "") -> str:
        return f"/s/{self.root}/{urllib.parse.quote(self.name, safe='')}{tail}"


def layout(app, title: str, main: str, *, page: str = "", data: dict[str, str] | None = None) -> str:
    attrs = f' data-page="{esc(page)}"' if page else ""
    attrs += "".join(f' data-{k}="{esc(v)}"' for k, v in (data or {}).items())
    fleet = '<a href="/fleet">fleet</a>' if app.db_url else ""
    return (
        "<!doctype html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        '<meta name="viewport" content="width=device-width, initial-scale=1">'
        f'<meta name="csrf-token" content="{esc(app.csrf_token)}">'
        f"<title>{esc(title)} - magrig cockpit</title>"
        '<link rel="stylesheet" href="/static/cockpit.css">'
        '<link rel="icon" href="/static/favicon.svg" type="image/svg+xml">'
        '<script src="/static/cockpit.js" defer></script>'
        f"</head><body{attrs}>"
        '<header class="top"><a class="brand" href="/">magrig cockpit</a>'
        f'<nav><a href="/">sessions</a>{fleet}</nav></header>'
        f"<main>{main}</main></body></html>\n"
    )


def table(header: list[str], rows: list[list[str]], *, raw_cells: bool = False, cls: str = "") -> str:
    """A table in a horizontally scrolling box (phones); cells are escaped unless `raw_cells` (already
    HTML, built from escaped parts)."""
    head = "".join(f"<th>{esc(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{c if raw_cells else esc(c)}</td>" for c in row) + "</tr>"
                   for row in rows)
    return (f'<div class="scroll"><table class="{esc(cls)}"><thead><tr>{head}</tr></thead>'
            f"<tbody>{body}</tbody></table></div>")


def _utc(t: float | None) -> str:
    from rig.report.sources import utc

    return utc(t)


def _fmt(x, spec: str = ".4g") -> str:
    return "-" if x is None else format(x, spec)


# --- sessions --------------------------------------------------------------------------------------------
def served_sessions(app) -> list[tuple[int, Path, list[SessionRef | tuple[str, str]]]]:
    """(folder index, folder, entries) for every served folder: a SessionRef for each session file that
    lies inside it (a symlink pointing out is left out, not followed)."""
    from rig.report.sessions import session_files
    from rig.session.schema import SESSION_SUFFIXES

    out = []
    for i, root in enumerate(app.roots):
        entries: list = []
        files = session_files(root, SESSION_SUFFIXES) if root.is_dir() else []
        for f in files:
            try:
                entries.append(SessionRef(i, f.name, session_file(app.roots, str(i), f.name)))
            except Refused:
                continue
        out.append((i, root, entries))
    return out


def sessions_page(app) -> str:
    from rig.report.sessions import COLUMNS, session_cells

    parts = ["<h1>Sessions</h1>"]
    for _, root, refs in served_sessions(app):
        rows = []
        for ref in refs:
            try:
                cells = session_cells(ref.path)
            except ERRORS as exc:
                reason = str(exc).removeprefix(f"{ref.path}: ")
                rows.append([esc(ref.name), f'<span class="bad">skipped: {esc(reason)}</span>'] + [""] * 7)
                continue
            link = f'<a href="{esc(ref.url())}">{esc(cells[0])}</a>'
            live = running_pid(ref.path) is not None
            badge = (f'<a class="badge live" href="{esc(ref.url("/live"))}">running: live view</a>' if live
                     else f'<a href="{esc(ref.url("/live"))}">live view</a>')
            rows.append([link, *(esc(c) for c in cells[1:]), badge])
        body = (table([*COLUMNS, ""], rows, raw_cells=True, cls="list") if rows
                else '<p class="muted">no session files here</p>')
        parts.append(f"<section><h2>{esc(root)}</h2>{body}</section>")
    return layout(app, "sessions", "".join(parts), page="sessions")


# --- one session -------------------------------------------------------------------------------------------
def session_page(app, ref: SessionRef) -> str:
    from rig.analysis.acceptance import verdict_text
    from rig.analysis.judged import RADIUS_LABEL, judged_cell, judged_fits, quality
    from rig.session.reader import SessionReader, runs_on_simulated_clock, simulated_text
    from rig.web.downloads import CALIBRATION_KINDS, SAMPLES_KIND, recorded_fits

    with SessionReader(ref.path) as reader:
        s = reader.summary()
        info = reader.info()
        accepted = reader.acceptance()
        fits = recorded_fits(reader)
        events = reader.events()
        judged_model, judged = judged_fits(reader)
    sim_clock = runs_on_simulated_clock(s["simulated"])
    running = running_pid(ref.path) is not None
    state = "running" if running else (s["exit_status"] or "not finished")

    def on_clocks(wall: float | None, run: float | None) -> str:
        """The wall-clock time, and the simulated clock's beside it when the run had one."""
        if wall is None:
            return "-"
        return _utc(wall) + (f" (simulated clock {_utc(run)})" if sim_clock and run is not None else "")

    summary = [
        ["plan", esc(s["plan"])], ["station", esc(s["station"])],
        ["started", esc(on_clocks(s["wall_started"], s["started"]))],
        ["ended", esc(on_clocks(s["wall_ended"], s["ended"]))],
        ["state", _live_text("s-state", state + (f" ({s['exit_code']})" if s["exit_code"] not in (None, state)
                                                 and not running else ""))],
        ["exit reason", _live_text("s-reason", s["exit_reason"] or "-")],
        ["points done", _live_text("s-points", f"{s['points_done']} of {s['points_planned']}" +
                                   (f" ({s['points_failed']} failed)" if s["points_failed"] else ""))],
        ["DUTs", esc(", ".join(s["duts"]) or "-")], ["acceptance", esc(verdict_text(accepted))],
        ["operator", esc(s["operator"] or "-")], ["software", esc(info["software_version"])],
        ["station file", esc(info["station_path"] or "not recorded")],
        ["devices", esc(simulated_text(s["simulated"]) + (
            "; on a simulated clock (event and fit times are that clock's)" if sim_clock else ""))],
        ["judged calibration", esc(judged_cell(judged_model, judged))],
    ]
    badge = ' <span id="run-state" class="badge state-running">running</span>' if running else ""
    parts = [
        f"<h1>{esc(ref.name)}{badge}</h1>",
        '<p class="buttons">'
        f'<a class="button" href="{esc(ref.url("/live"))}">live view</a> '
        f'<a class="button" href="{esc(ref.url("/report"))}">report</a></p>',
        f"<section><h2>Summary</h2>{table(['', ''], summary, raw_cells=True, cls='kv')}</section>",
    ]
    if running:  # the live view's parts, moved by its stream (cockpit.js); the rest is shown when it ends
        parts.append(f'<div class="cards">{PROGRESS_CARDS}</div>{TEMPERATURES}{DUT_TABLE}'
                     '<p id="stream-note" class="muted"></p>')
    if accepted:
        rows = [[r["dut"], str(r["model"]).upper(), r["verdict"], r["failed"] or "-",
                 _fmt(r["heldout_rms_nt"]), _fmt(r["fit_rms_nt"]), r["notes"] or "-"] for r in accepted]
        parts.append("<section><h2>Acceptance</h2>" + table(
            ["DUT", "model", "verdict", "failed criteria", "held-out RMS (nT)", "fit RMS (nT)", "notes"],
            rows) + "</section>")
    cal_rows = []
    for (dut, model), fit in sorted(fits.items()):
        try:
            recorded = json.loads(fit["calibration_json"])
        except ValueError:
            recorded = {}
        stats = recorded.get("stats", {})
        q = quality(stats, recorded.get("uncertainty"))
        links = " ".join(
            f'<a href="{esc(_download_url(ref, kind, dut, model))}" download>{esc(label)}</a>'
            for kind, (label, _, _) in CALIBRATION_KINDS.items())
        check = ("-" if q.radius_nt is None else
                 f'<span class="bad">RMS &gt; radius: {esc(q.exceeds_text())}</span>' if q.exceeds else "ok")
        fitted = str(recorded.get("created_utc") or "-") + (
            f" (simulated clock {_utc(fit['t'])})" if sim_clock else "")
        judged_here = judged[dut]["model"] if dut in judged else judged_model  # T36 where it was chosen
        cal_rows.append([esc(dut), esc(model + (" (judged)" if model == judged_here else "")),
                         esc(stats.get("n_used", "-")), esc(_fmt(fit["residual_rms_nt"])),
                         esc(q.uncertainty_text()), check, esc(q.dominant or "-"), esc(fitted), links])
    calibrations = (table(["DUT", "model", "samples used", "RMS after (nT)", RADIUS_LABEL,
                           "check", "largest uncertainty contribution", "fitted (wall clock, UTC)",
                           "downloads"], cal_rows, raw_cells=True)
                    if cal_rows else '<p class="muted">no calibration recorded yet</p>')
    parts.append(f"<section><h2>Calibrations</h2>{calibrations}</section>")
    certified = sorted({dut for dut, _ in fits})
    links = " ".join(f'<a href="{esc(ref.url("/certificate?" + urllib.parse.urlencode({"dut": d})))}">'
                     f"{esc(d)}</a>" for d in certified)
    parts.append("<section><h2>Calibration certificates</h2>"
                 f"<p>{links or 'none yet (the run writes its calibrations at its end)'}</p></section>")
    sample_links = " ".join(f'<a href="{esc(_download_url(ref, SAMPLES_KIND, dut))}" download>{esc(dut)}</a>'
                            for dut in s["duts"])
    parts.append("<section><h2>Samples (CSV, as rig export writes them)</h2>"
                 f"<p>{sample_links or 'no samples yet'}</p></section>")
    shown = events[-MAX_EVENTS_SHOWN:]
    rows = [[_utc(e.t), e.kind, e.code.value, e.point_id or "", e.device or "", e.message]
            for e in reversed(shown)]
    note = (f'<p class="muted">the newest {len(shown)} of {len(events)} events</p>'
            if len(events) > len(shown) else "")
    header = ["time (simulated clock)" if sim_clock else "time (UTC)", "kind", "code", "point", "device",
              "message"]
    listing = table(header, rows, cls="events").replace('<table class="events">',
                                                        '<table class="events" id="event-table">', 1)
    parts.append(f"<section><h2>Events</h2>{note}{listing}</section>")
    data = {"session": ref.name, "last-event": str(events[-1].id if events else 0)}
    if running:
        data["events"] = ref.url("/events")
    return layout(app, ref.name, "".join(parts), page="session", data=data)


def _live_text(element_id: str, text: str) -> str:
    """A summary value the page script keeps current while the run goes on."""
    return f'<span id="{element_id}">{esc(text)}</span>'


def _download_url(ref: SessionRef, kind: str, dut: str, model: str | None = None) -> str:
    query = {"what": kind, "dut": dut} | ({"model": model} if model else {})
    return ref.url("/download?" + urllib.parse.urlencode(query))


# --- live ----------------------------------------------------------------------------------------------
# What the live view and a running session's page share; cockpit.js fills them from the same stream.
PROGRESS_CARDS = """
  <section class="card"><h2>Progress</h2><progress id="progress" max="1" value="0"></progress>
    <p id="progress-text">-</p><p id="eta" class="muted"></p></section>
  <section class="card"><h2>Now</h2><p id="current">-</p><p id="target" class="muted"></p></section>"""
TEMPERATURES = """
<section><h2>Temperatures</h2><div id="chart" class="chart"></div>
  <p id="legend" class="legend"></p></section>"""
DUT_TABLE = """
<section><h2>DUTs</h2><div class="scroll"><table id="duts"><thead><tr><th>DUT</th><th>temperature (degC)</th>
  <th>samples</th><th>running T24 RMS (nT)</th><th>acceptance</th></tr></thead><tbody></tbody></table></div>
</section>"""


def live_page(app, ref: SessionRef) -> str:
    main = f"""
<h1><span class="name">{esc(ref.name)}</span> <span id="run-state" class="badge">connecting</span></h1>
<p class="meta"><span id="meta"></span> <a href="{esc(ref.url())}">session page</a></p>
<div class="cards">{PROGRESS_CARDS}
  <section class="card" id="actions" hidden><h2>Operator</h2>
    <p class="buttons"><button type="button" id="ask-pause">Pause at the next safe point</button>
    <button type="button" id="ask-abort" class="danger">Abort to the safe state</button></p>
    <div id="confirm" class="confirm" hidden><p id="confirm-text"></p>
      <p class="buttons"><button type="button" id="confirm-yes">Yes</button>
      <button type="button" id="confirm-no">Cancel</button></p></div>
    <p id="action-status" role="status" class="muted"></p></section>
</div>{TEMPERATURES}{DUT_TABLE}
<section><h2>Events</h2><ol id="events" class="events"></ol></section>
<p id="stream-note" class="muted"></p>"""
    data = {"events": ref.url("/events"), "action": ref.url("/action"), "session": ref.name}
    return layout(app, f"live: {ref.name}", main, page="live", data=data)


# --- fleet ------------------------------------------------------------------------------------------------
FLEET_FILTERS = ("station", "dut", "since", "until", "verdict")


def fleet_page(app, query: dict[str, str]) -> str:
    from rig.fleet import FleetError
    from rig.fleet.query import LISTING_COLUMNS, Filters, list_sessions, listing_cells, parse_date
    from rig.fleet.schema import connect

    given = {k: query.get(k, "").strip() for k in FLEET_FILTERS}
    problem, rows = "", []
    try:
        verdict = given["verdict"].upper() or None
        if verdict not in (None, "PASS", "FAIL"):
            raise FleetError(f"verdict: {given['verdict']!r} is not PASS or FAIL")
        filters = Filters(station=given["station"] or None, dut=given["dut"] or None,
                          since=parse_date(given["since"], "since") if given["since"] else None,
                          until=parse_date(given["until"], "until") if given["until"] else None,
                          verdict=verdict)
        with connect(app.db_url, create=False) as conn:
            rows = list_sessions(conn, filters)
    except FleetError as exc:
        problem = str(exc)
    except Exception as exc:  # psycopg: no such table before the first push, a lost connection
        problem = f"cannot list the fleet database: {str(exc).strip().splitlines()[0] if str(exc) else exc}"
    form = _fleet_form(given)
    parts = ["<h1>Fleet</h1>", form]
    if problem:
        parts.append(f'<p class="bad">{esc(problem)}</p>')
    parts.append(f"<section><h2>Rigs</h2>{_rigs_table(rows)}</section>")
    parts.append(f'<section><h2>Verdicts over time</h2><div class="chart">{verdict_chart(rows)}</div>'
                 '<p class="legend"><span class="key pass">PASS</span> <span class="key fail">FAIL</span> '
                 '<span class="key none">no verdict</span> (sessions per day started, UTC)</p></section>')
    listing = table(list(LISTING_COLUMNS), [listing_cells(r) for r in rows], cls="list") if rows else (
        '<p class="muted">no sessions match</p>')
    parts.append(f"<section><h2>Sessions ({len(rows)})</h2>{listing}</section>")
    return layout(app, "fleet", "".join(parts), page="fleet")


def _fleet_form(given: dict[str, str]) -> str:
    def field(name: str, label: str, placeholder: str = "") -> str:
        return (f'<label>{esc(label)} <input name="{name}" value="{esc(given[name])}" '
                f'placeholder="{esc(placeholder)}"></label>')

    chosen = given["verdict"].upper()
    options = "".join(f'<option value="{v}"{" selected" if chosen == v else ""}>{v or "any"}</option>'
                      for v in ("", "PASS", "FAIL"))
    return ('<form class="filters" method="get" action="/fleet">'
            + field("station", "station") + field("dut", "DUT or serial")
            + field("since", "since", "2026-03-01") + field("until", "until", "2026-04-01")
            + f'<label>verdict <select name="verdict">{options}</select></label>'
            + '<button type="submit">filter</button></form>')


def _rigs_table(rows: list[dict]) -> str:
    rigs: dict[str, dict] = {}
    for r in rows:
        rig = rigs.setdefault(r["station_name"] or "-", {"n": 0, "PASS": 0, "FAIL": 0, "last": None})
        rig["n"] += 1
        if r["verdict"] in ("PASS", "FAIL"):
            rig[r["verdict"]] += 1
        if r["started_utc"] and (rig["last"] is None or r["started_utc"] > rig["last"]):
            rig["last"] = r["started_utc"]
    if not rigs:
        return '<p class="muted">none</p>'
    body = [[name, str(v["n"]), str(v["PASS"]), str(v["FAIL"]),
             v["last"].strftime("%Y-%m-%d %H:%M") if v["last"] else "-"] for name, v in sorted(rigs.items())]
    return table(["station", "sessions", "PASS", "FAIL", "last started (UTC)"], body)


def verdict_chart(rows: list[dict], width: int = 720, height: int = 200) -> str:
    """Sessions started per day, stacked by verdict, as an inline SVG (drawn here: no script needed)."""
    days: dict[dt.date, dict[str, int]] = {}
    for r in rows:
        if r["started_utc"] is None:
            continue
        day = days.setdefault(r["started_utc"].astimezone(dt.UTC).date(), {"PASS": 0, "FAIL": 0, "none": 0})
        day[r["verdict"] if r["verdict"] in ("PASS", "FAIL") else "none"] += 1
    if not days:
        return '<p class="muted">no sessions to draw</p>'
    first, last = min(days), max(days)
    span = (last - first).days + 1
    top = max(sum(d.values()) for d in days.values())
    left, bottom, pad = 36, 24, 8
    plot_w, plot_h = width - left - pad, height - bottom - pad
    bar_w = max(plot_w / span * 0.8, 1.0)
    parts = [f'<svg class="verdicts" width="{width}" height="{height}" viewBox="0 0 {width} {height}" '
             f'role="img" aria-label="sessions per day by verdict, {esc(first)} to {esc(last)}">']
    for frac in (0.0, 0.5, 1.0):
        y = pad + plot_h * (1 - frac)
        parts.append(f'<line class="grid" x1="{left}" x2="{width - pad}" y1="{y:.1f}" y2="{y:.1f}"/>'
                     f'<text class="tick" x="{left - 4}" y="{y + 4:.1f}" text-anchor="end">'
                     f"{top * frac:g}</text>")
    for day, counts in sorted(days.items()):
        x = left + (day - first).days / span * plot_w + (plot_w / span - bar_w) / 2
        y = pad + plot_h
        for key in ("PASS", "FAIL", "none"):
            h = counts[key] / top * plot_h
            if h:
                y -= h
                parts.append(f'<rect class="{key.lower()}" x="{x:.1f}" y="{y:.1f}" width="{bar_w:.1f}" '
                             f'height="{h:.1f}"><title>{esc(day)}: {counts[key]} {esc(key)}</title></rect>')
    parts.append(f'<text class="tick" x="{left}" y="{height - 6}">{esc(first)}</text>'
                 f'<text class="tick" x="{width - pad}" y="{height - 6}" text-anchor="end">{esc(last)}</text>'
                 "</svg>")
    return "".join(parts)


# --- a report being built ----------------------------------------------------------------------------------
def report_building_page(app, ref: SessionRef, progress: str) -> str:
    """What the report's address shows while the report is built (the response's Refresh header reloads it
    until the report itself comes)."""
    return layout(app, f"report of {ref.name}",
                  f"<h1>Report of {esc(ref.name)}</h1>"
                  f'<p id="report-progress">Building the report: {esc(progress)}.</p>'
                  "<p>This page reloads itself until the report is ready.</p>"
                  f'<p><a href="{esc(ref.url())}">back to the session</a></p>', page="report-building")


# --- errors -----------------------------------------------------------------------------------------------
def error_page(app, status: int, message: str) -> str:
    return layout(app, f"{status}", f'<h1>{status}</h1><p class="bad">{esc(message)}</p>'
                  '<p><a href="/">sessions</a></p>', page="error")
