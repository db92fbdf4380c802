"""The cockpit: `rig serve`, a small web server on top of rig/ for watching and steering campaigns.

    guard.py    who may ask for what: Host and token checks, CSRF, which files a request may name, escaping
    live.py     the live view of a session file, read incrementally through rig.session.reader.SessionReader
    pages.py    the HTML pages (sessions, a session, its live view, the fleet)
    downloads.py  calibration files, firmware exports and samples CSV, made by the CLI's own functions
    server.py   the HTTP server (http.server.ThreadingHTTPServer), routes, server-sent events, actions
    static/     the page script (plain JS, its own SVG plot), the style sheet, the icon

The server opens session files only through SessionReader (read-only) and never writes one; operator
actions leave a request for the run's engine (rig/session/inbox.py), which decides when it is safe to act.
"""
