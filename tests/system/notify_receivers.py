"""Receivers for the run's word to the operator, on loopback only: a local SMTP server (aiosmtpd) and a local
HTTP receiver for Apprise's json:// webhook. Each keeps every message it got, as (title, body).

    with smtp_receiver() as mail, http_receiver() as hook:
        urls = [mail.url, hook.url]        # Apprise URLs pointing at them
        ... mail.messages, hook.messages   # [(title, body)], in arrival order
"""

from __future__ import annotations

import contextlib
import email
import json
import socket
import threading
from email import policy
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer

LOOPBACK = "127.0.0.1"


class _Inbox:
    def __init__(self, url: str):
        self.url = url
        self.messages: list[tuple[str, str]] = []
        self.lock = threading.Lock()

    def add(self, title: str, body: str) -> None:
        with self.lock:
            self.messages.append((title, body.replace("\r\n", "\n").strip()))  # mail lines end in CRLF


def _free_port() -> int:
    with socket.socket() as s:  # aiosmtpd's controller needs the port before it starts
        s.bind((LOOPBACK, 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def smtp_receiver():
    from aiosmtpd.controller import Controller

    class Handler:
        async def handle_DATA(self, server, session, envelope):  # noqa: N802 - aiosmtpd's hook name
            mail = email.message_from_bytes(envelope.original_content or envelope.content,
                                            policy=policy.default)
            part = mail.get_body(preferencelist=("plain", "html"))
            inbox.add(str(mail["Subject"]), part.get_content() if part is not None else "")
            return "250 OK"

    port = _free_port()
    inbox = _Inbox(f"mailto://{LOOPBACK}:{port}?from=rig@example.org&to=operator@example.org")
    controller = Controller(Handler(), hostname=LOOPBACK, port=port)
    controller.start()
    try:
        yield inbox
    finally:
        controller.stop()


@contextlib.contextmanager
def http_receiver():
    class Handler(BaseHTTPRequestHandler):
        def do_POST(self):  # noqa: N802 - http.server's hook name
            length = int(self.headers.get("Content-Length") or 0)
            payload = json.loads(self.rfile.read(length) or b"{}")
            inbox.add(str(payload.get("title", "")), str(payload.get("message", "")))
            self.send_response(200)
            self.end_headers()

        def log_message(self, *args):
            pass

    server = ThreadingHTTPServer((LOOPBACK, 0), Handler)
    inbox = _Inbox(f"json://{LOOPBACK}:{server.server_address[1]}/magrig")
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield inbox
    finally:
        server.shutdown()
        server.server_close()
