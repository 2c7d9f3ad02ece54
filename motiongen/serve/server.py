"""The web server of `motiongen serve`: the page, its static files and the JSON API
(docs/serve.md), on the standard library's threading HTTP server.

Safe by default: the scene and checkpoint are fixed at launch and no request names a file (the
static files are the package's own, looked up under one folder); request bodies are capped at
`MAX_BODY` bytes and goal lists at the session's `max_pending`; a malformed request is HTTP 400
with a one-line reason, and the server goes on.
"""

from __future__ import annotations

import json
import mimetypes
import threading
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from urllib.parse import parse_qs, urlparse

from motiongen.errors import ConfigError
from motiongen.serve.downloads import DOWNLOADS, download
from motiongen.serve.requests import RequestError, parse_goals_body, parse_int, parse_playing
from motiongen.serve.session import LiveSession

MAX_BODY = 64 * 1024               # bytes: 100 goals as JSON take ~6 KB
STATIC_DIR = Path(__file__).parent / "static"
mimetypes.add_type("text/javascript", ".js")
mimetypes.add_type("model/gltf-binary", ".glb")


class App:
    """What the handler serves: the session, /api/info, and the scene and body as glb bytes."""

    def __init__(self, session: LiveSession, info: dict, scene_glb: bytes | None, body_glb: bytes, body_model,
                 action_seconds: float = 3.0):
        self.session, self.info, self.scene_glb, self.body_glb = session, info, scene_glb, body_glb
        self.body_model, self.action_seconds = body_model, float(action_seconds)


class Handler(BaseHTTPRequestHandler):
    app: App                       # set on the subclass `make_server` builds
    server_version = "motiongen"
    protocol_version = "HTTP/1.1"

    def log_message(self, format, *args):  # noqa: A002: the base class's name
        pass                                # one line per request would drown the console

    # ---- routing ---------------------------------------------------------------------------

    def do_GET(self):
        self._guard(self._get)

    def do_POST(self):
        self._guard(self._post)

    def do_DELETE(self):
        self._guard(self._delete)

    def _guard(self, fn):
        url = urlparse(self.path)
        try:
            fn(url.path, parse_qs(url.query))
        except (RequestError, ConfigError) as e:
            self._json({"error": str(e).splitlines()[0]}, getattr(e, "status", HTTPStatus.BAD_REQUEST))
        except (BrokenPipeError, ConnectionResetError):
            pass                            # the client went away; nothing of the session is lost

    def _get(self, path: str, query: dict):
        app = self.app
        if path in ("/", "/index.html"):
            return self._static("index.html")
        if path.startswith("/static/"):
            return self._static(path[len("/static/"):])
        if path == "/api/info":
            return self._json(app.info)
        if path == "/api/state":
            return self._json(app.session.state())
        if path == "/api/frames":
            start = parse_int(query, "from", 0)
            rev = parse_int(query, "rev", None)
            return self._json(app.session.frames(start, rev))
        if path == "/api/scene.glb" and app.scene_glb is not None:
            return self._bytes(app.scene_glb, "model/gltf-binary")
        if path == "/api/body.glb":
            return self._bytes(app.body_glb, "model/gltf-binary")
        if path == "/api/download":
            fmt = (query.get("format") or ["npz"])[0]
            if fmt not in DOWNLOADS:
                raise RequestError(f"format: expected one of {', '.join(DOWNLOADS)}, got {fmt!r}")
            data = download(fmt, app.session, app.body_model)
            return self._bytes(data, DOWNLOADS[fmt], f"motion.{fmt}")
        raise RequestError(f"no such page: {path}", HTTPStatus.NOT_FOUND)

    def _post(self, path: str, query: dict):
        body = self._body()
        if path == "/api/goals":
            goals, replace = parse_goals_body(body, self.app.action_seconds)
            n = self.app.session.add_goals(goals, replace)
            return self._json({"pending": n, "accepted": len(goals)})
        if path == "/api/play":
            self.app.session.set_playing(parse_playing(body))
            return self._json(self.app.session.state())
        raise RequestError(f"no such endpoint: POST {path}", HTTPStatus.NOT_FOUND)

    def _delete(self, path: str, query: dict):
        if path == "/api/goals":
            self.app.session.clear_goals()
            return self._json({"pending": 0})
        raise RequestError(f"no such endpoint: DELETE {path}", HTTPStatus.NOT_FOUND)

    # ---- responses -------------------------------------------------------------------------

    def _body(self):
        try:
            n = int(self.headers.get("Content-Length") or 0)
        except ValueError:
            raise RequestError("Content-Length is not a number") from None
        if n > MAX_BODY:
            raise RequestError(f"request body of {n} bytes; at most {MAX_BODY}", HTTPStatus.REQUEST_ENTITY_TOO_LARGE)
        raw = self.rfile.read(n) if n > 0 else b""
        try:
            return json.loads(raw) if raw.strip() else None
        except (UnicodeDecodeError, json.JSONDecodeError) as e:
            raise RequestError(f"body is not JSON: {e}") from None

    def _static(self, rel: str):
        root = STATIC_DIR.resolve()
        path = (root / rel).resolve()
        if not path.is_relative_to(root) or not path.is_file():
            raise RequestError(f"no such file: /static/{rel}", HTTPStatus.NOT_FOUND)
        kind = mimetypes.guess_type(path.name)[0] or "application/octet-stream"
        self._bytes(path.read_bytes(), kind)

    def _json(self, obj, status=HTTPStatus.OK):
        self._bytes(json.dumps(obj).encode(), "application/json", status=status)

    def _bytes(self, data: bytes, kind: str, filename: str | None = None, status=HTTPStatus.OK):
        self.send_response(status)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(data)))
        self.send_header("Cache-Control", "no-store")
        if filename:
            self.send_header("Content-Disposition", f'attachment; filename="{filename}"')
        self.end_headers()
        self.wfile.write(data)


def make_server(app: App, host: str = "127.0.0.1", port: int = 8000) -> ThreadingHTTPServer:
    """An HTTP server for `app` bound to host:port (port 0: a free one); serve it with
    `serve_forever`. OSError when the port is taken."""
    handler = type("BoundHandler", (Handler,), {"app": app})
    server = ThreadingHTTPServer((host, port), handler)
    server.daemon_threads = True
    return server


def serve_in_thread(app: App, host: str = "127.0.0.1", port: int = 0) -> tuple[ThreadingHTTPServer, str]:
    """Start the session and a server in background threads (tests, benchmarks): (server, base URL).
    Stop with `server.shutdown(); app.session.stop()`."""
    server = make_server(app, host, port)
    app.session.start()
    threading.Thread(target=server.serve_forever, name="motiongen-http", daemon=True).start()
    h, p = server.server_address[:2]
    return server, f"http://{h}:{p}"
