"""The console's HTTP side: one page (hil/console/static/), its JSON API, Server-Sent Events for the live
data, and the run files of the history, with the standard library's ThreadingHTTPServer.

    GET  /                       the page (and /static/NAME: its script and style)
    GET  /api/info               who is logged in, their role and the actions it allows, the rig the console
                                 is pinned to, the fault catalog
    GET  /api/status             the service's last status
    GET  /api/history?limit=N&before=RUN
    GET  /api/events             Server-Sent Events: status (1 Hz), live (20 Hz while a run goes), safety,
                                 latch (the e-stop latch and the supervisor's last word), history
    GET  /runs/RUN/NAME          a file of a past run's folder (which ones: hil/history.py)
    POST /api/start {"scenario": NAME} | /api/stop | /api/estop {"cut_power": bool} | /api/reset
         /api/inject {"kind": ..., ...} | /api/clear {"number": N or null}
    POST /api/login {"name": ..., "password": ...} | /api/logout      (a console with accounts)

Every answer but the page, its files and the run files is JSON; a bad request is a 4xx with {"ok": false,
"error": ...}, never a traceback. Requests must name this server in Host (a DNS-rebinding page cannot reach
it) and POSTs must be JSON (a foreign page's form cannot post one without the browser asking first, and the
console never answers that question), so a page elsewhere in the operator's browser cannot press its buttons.
A console with accounts (hil/console/accounts.py) serves nothing but the page to a person not logged in, and
every action is written to its audit log with who asked, from where, and the answer.
"""

from __future__ import annotations

import ipaddress
import json
import logging
import socket
import ssl
import threading
import time
from collections.abc import Callable
from datetime import datetime
from http import HTTPStatus
from http.cookies import CookieError, SimpleCookie
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from urllib.parse import parse_qs, unquote, urlsplit

from hil.console.accounts import COOKIE, Account, LoginRefused, Person, Sessions
from hil.console.events import Broadcast
from hil.console.rig_link import Refused, RigLink
from hil.console.roles import EVERY_ACTION, allowed_to

log = logging.getLogger(__name__)

STATIC_TYPES = {".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8"}
STATIC_TYPES |= {".css": "text/css; charset=utf-8", ".png": "image/png", ".svg": "image/svg+xml"}
FILE_TYPES = {".png": "image/png", ".json": "application/json", ".md": "text/plain; charset=utf-8"}
FILE_TYPES |= {".html": "text/html; charset=utf-8", ".xml": "application/xml", ".log": "text/plain"}
MAX_BODY = 64 * 1024
MAX_PAGES = 16
"""Live pages (SSE streams) at a time: each holds a thread; more are refused (503) rather than grown."""
KEEPALIVE = 1.0
"""s between SSE comments when nothing happens: a page that went away is noticed at the next write."""
WRITE_TIMEOUT = 15.0
"""s a socket write may block (a page that stopped reading) before its thread gives up."""


class ListenError(ValueError):
    """--listen / --tls-* cannot be used as given: one line naming the flag."""


def parse_listen(text: str) -> tuple[str, int]:
    """HOST:PORT (an IP address; [::1]:PORT for IPv6; port 0: a free one)."""
    host, sep, port = text.rpartition(":")
    host = host.strip("[]")
    try:
        if not sep:
            raise ValueError
        ipaddress.ip_address(host)
        number = int(port)
        if not 0 <= number <= 65535:
            raise ValueError
    except ValueError:
        raise ListenError(
            f"--listen {text!r}: expected IP:PORT, e.g. 127.0.0.1:8080 (port 0: a free one)"
        ) from None
    return host, number


def is_loopback(host: str) -> bool:
    return ipaddress.ip_address(host).is_loopback


def tls_context(cert: str | None, key: str | None) -> ssl.SSLContext | None:
    if cert is None and key is None:
        return None
    if cert is None or key is None:
        raise ListenError("--tls-cert and --tls-key go together: give both")
    context = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
    context.minimum_version = ssl.TLSVersion.TLSv1_2
    try:
        context.load_cert_chain(cert, key)
    except (OSError, ssl.SSLError) as exc:
        raise ListenError(f"--tls-cert {cert} / --tls-key {key}: cannot load: {exc}") from None
    return context


def check_exposure(listen: tuple[str, int], tls: ssl.SSLContext | None, accounts: bool) -> None:
    """Off loopback the page would cross a network in the clear, or act for whoever reaches it: refused
    without TLS and without accounts."""
    host, port = listen
    if is_loopback(host):
        return
    if tls is None:
        raise ListenError(
            f"--listen {host}:{port} is not loopback: give --tls-cert and --tls-key to expose the console"
        )
    if not accounts:
        raise ListenError(
            f"--listen {host}:{port} is not loopback: give --accounts FILE (who may log in and their roles; "
            "pure-hil accounts add) to expose the console"
        )


def audit_to_log(line: str) -> None:
    log.info("%s", line)


def _static() -> dict[str, tuple[bytes, str]]:
    """The page's files, read once from the package (they ship in the wheel)."""
    folder = resources.files("hil.console") / "static"
    files = {}
    for entry in folder.iterdir():
        suffix = "." + entry.name.rpartition(".")[2]
        if entry.is_file() and suffix in STATIC_TYPES:
            files[entry.name] = (entry.read_bytes(), STATIC_TYPES[suffix])
    return files


class Console(ThreadingHTTPServer):
    daemon_threads = True  # a page's thread never holds the process open
    block_on_close = False

    def __init__(
        self,
        link: RigLink,
        info: dict,
        listen: tuple[str, int] = ("127.0.0.1", 0),
        tls: ssl.SSLContext | None = None,
        accounts: dict[str, Account] | None = None,
        audit: Callable[[str], None] = audit_to_log,
    ):
        """`info`: what /api/info adds (the bench, the fault catalog); `accounts`: who may log in (None: no
        login, the page acts with the console's role; only on loopback); `audit`: where each action's line
        goes."""
        check_exposure(listen, tls, bool(accounts))
        host, port = listen
        self.address_family = socket.AF_INET6 if ":" in host else socket.AF_INET
        try:
            super().__init__((host, port), Handler)
        except OSError as exc:
            raise ListenError(f"--listen {host}:{port}: {exc.strerror or exc}") from None
        self.link, self.tls = link, tls
        self.role = link.role
        self.info = info
        self.sessions = Sessions(accounts) if accounts else None
        self.audit = audit
        self.static = _static()
        self.pages = threading.BoundedSemaphore(MAX_PAGES)
        port = self.server_address[1]
        shown = f"[{host}]" if ":" in host else host
        self.url = f"{'https' if tls else 'http'}://{shown}:{port}/"
        hosts = {f"{shown}:{port}"} | ({f"localhost:{port}"} if is_loopback(host) else set())
        self.hosts = frozenset(hosts)
        self._thread: threading.Thread | None = None

    def finish_request(self, request, client_address) -> None:
        # TLS is set up here, in the request's own thread: a slow handshake never holds up accept().
        if self.tls is not None:
            request.settimeout(WRITE_TIMEOUT)
            try:
                request = self.tls.wrap_socket(request, server_side=True)
            except (OSError, ssl.SSLError) as exc:
                log.info("TLS handshake with %s failed: %s", client_address, exc)
                return
        super().finish_request(request, client_address)

    def start(self) -> Console:
        self._thread = threading.Thread(target=self.serve_forever, name="console-http", daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        self.link.events.close()  # live pages end their streams
        self.shutdown()
        self.server_close()
        if self._thread is not None:
            self._thread.join(5.0)


class Handler(BaseHTTPRequestHandler):
    server: Console
    protocol_version = "HTTP/1.1"
    timeout = WRITE_TIMEOUT

    def log_message(self, format: str, *args) -> None:
        log.debug("%s " + format, self.address_string(), *args)

    # --------------------------------------------------------------------------------------- answers
    def _send(self, status: int, body: bytes, content_type: str, extra: dict | None = None) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        self.send_header("X-Content-Type-Options", "nosniff")
        for name, value in (extra or {}).items():
            self.send_header(name, value)
        self.end_headers()
        self.wfile.write(body)

    def _json(self, status: int, body: dict, extra: dict | None = None) -> None:
        self._send(status, json.dumps(body).encode(), "application/json", extra)

    def _error(self, status: int, message: str, **more) -> None:
        self._json(status, {"ok": False, "error": message, **more})

    def _guarded(self, handle) -> None:
        try:
            host = self.headers.get("Host", "")
            if host not in self.server.hosts:
                self._error(
                    HTTPStatus.MISDIRECTED_REQUEST, f"this console answers to {sorted(self.server.hosts)}"
                )
                return
            handle()
        except (BrokenPipeError, ConnectionResetError, TimeoutError, ssl.SSLError):
            self.close_connection = True  # the page went away; nothing to answer
        except Exception as exc:  # one line to the page, the traceback to the log
            log.exception("console: %s %s", self.command, self.path)
            try:
                self._error(HTTPStatus.INTERNAL_SERVER_ERROR, f"internal error: {type(exc).__name__}: {exc}")
            except OSError:
                self.close_connection = True

    def do_GET(self) -> None:
        self._guarded(self._get)

    def do_POST(self) -> None:
        self._guarded(self._post)

    def _method_not_allowed(self) -> None:
        self._guarded(
            lambda: self._error(HTTPStatus.METHOD_NOT_ALLOWED, f"{self.command} is not served here")
        )

    do_HEAD = do_PUT = do_DELETE = do_PATCH = do_OPTIONS = _method_not_allowed

    # ------------------------------------------------------------------------------------------- who
    def _token(self) -> str | None:
        try:
            cookie = SimpleCookie(self.headers.get("Cookie", ""))
        except CookieError:
            return None
        morsel = cookie.get(COOKIE)
        return None if morsel is None else morsel.value

    def _person(self) -> Person | None:
        """Who asks: the person logged in, or the console's own role where it has no accounts (None: a
        console with accounts, and nobody logged in)."""
        sessions = self.server.sessions
        if sessions is None:
            return Person("", self.server.role)
        return sessions.person(self._token(), time.monotonic())

    def _logged_in(self) -> Person | None:
        """The person asking, or None after answering 401 (the page then shows its login)."""
        person = self._person()
        if person is None:
            self._error(HTTPStatus.UNAUTHORIZED, "log in first", login=True)
        return person

    def _audit(self, person: Person | None, action: str, status: int, detail: str) -> None:
        who = "(not logged in)" if person is None else f"{person.name or '(no login)'} ({person.role})"
        stamp = datetime.now().astimezone().isoformat(timespec="seconds")
        line = (
            f"console audit {stamp} {who} from {self.client_address[0]}: {action} -> {int(status)} {detail}"
        )
        # One line per action, whatever a name typed at the login holds: no forged second line.
        self.server.audit("".join(c if c.isprintable() else repr(c)[1:-1] for c in line))

    # ------------------------------------------------------------------------------------------- GET
    def _get(self) -> None:
        url = urlsplit(self.path)
        path = url.path
        if path in ("/", "/index.html"):
            body, kind = self.server.static["index.html"]
            self._send(HTTPStatus.OK, body, kind)
            return
        if path.startswith("/static/"):
            found = self.server.static.get(path.removeprefix("/static/"))
            if found is None:
                self._error(HTTPStatus.NOT_FOUND, f"no static file {path}")
            else:
                self._send(HTTPStatus.OK, *found)
            return
        person = self._logged_in()
        if person is None:
            return
        if path == "/api/info":
            self._info(person)
        elif path == "/api/status":
            status = self.server.link.status
            if status is None:
                self._error(
                    HTTPStatus.BAD_GATEWAY, "the service has not answered (is `pure-hil serve` running?)"
                )
            else:
                self._json(HTTPStatus.OK, status)
        elif path == "/api/history":
            self._history(parse_qs(url.query))
        elif path == "/api/events":
            self._events()
        elif path.startswith("/runs/"):
            self._run_file(path)
        else:
            self._error(HTTPStatus.NOT_FOUND, f"nothing at {path}")

    def _info(self, person: Person) -> None:
        server = self.server
        actions = allowed_to(person.role, server.role)
        self._json(
            HTTPStatus.OK,
            {
                "ok": True,
                **server.info,
                "role": person.role,
                "person": person.name or None,
                "console_role": server.role,
                "login": server.sessions is not None,
                "actions": sorted(actions),
                "card": server.link.pinned,
                "source": self._source(person),
            },
        )

    def _source(self, person: Person) -> str:
        """Who this person's e-stops and resets say they are from (the supervisor's `estop_by`)."""
        return f"console {person.role} {person.name}" if person.name else self.server.link.source

    def _history(self, query: dict[str, list[str]]) -> None:
        numbers = {}
        for name, default in (("limit", "50"), ("before", None)):
            text = query.get(name, [default])[-1]
            if text is None:
                continue
            if not text.isdigit() or int(text) < 1:
                self._error(HTTPStatus.BAD_REQUEST, f"{name}: expected a whole number >= 1, got {text!r}")
                return
            numbers[name] = int(text)
        reply = self.server.link.history(min(numbers["limit"], 500), numbers.get("before"))
        self._json(HTTPStatus.OK if reply.get("ok") else HTTPStatus.BAD_GATEWAY, reply)

    def _run_file(self, path: str) -> None:
        # /runs/RUN/NAME: the raw path is split before decoding, so an encoded '/' stays inside NAME, and the
        # service refuses any NAME that is not a plain file name of that run's folder.
        parts = path.split("/")
        if len(parts) != 4 or not parts[2].isdigit():
            self._error(HTTPStatus.NOT_FOUND, f"expected /runs/RUN/FILE, got {path}")
            return
        run, name = int(parts[2]), unquote(parts[3])
        try:
            size, chunks = self.server.link.file(run, name)
        except Refused as exc:
            self._error(exc.status, str(exc))
            return
        suffix = "." + name.rpartition(".")[2]
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", FILE_TYPES.get(suffix, "application/octet-stream"))
        self.send_header("Content-Length", str(size))
        self.send_header("X-Content-Type-Options", "nosniff")
        # A run's HTML report is shown, never run as part of the console's origin.
        self.send_header("Content-Security-Policy", "sandbox")
        self.end_headers()
        try:
            for chunk in chunks:
                self.wfile.write(chunk)
        except Refused as exc:  # the service went away mid-file: the page sees a short body
            log.warning("run %s file %s: %s", run, name, exc)
            self.close_connection = True

    def _events(self) -> None:
        pages = self.server.pages
        if not pages.acquire(blocking=False):
            self._error(HTTPStatus.SERVICE_UNAVAILABLE, f"{MAX_PAGES} live pages are open already")
            return
        try:
            events = self.server.link.events
            self.send_response(HTTPStatus.OK)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.close_connection = True
            seq, first = events.snapshot()
            self.wfile.write(b"retry: 1000\n\n" + b"".join(first))
            self.wfile.flush()
            # A session that ends (logged out, expired) ends its stream at the next event or keepalive.
            while not events.closed and self._person() is not None:
                seq, newer = events.wait(seq, KEEPALIVE)
                self.wfile.write(b"".join(newer) if newer else b": keepalive\n\n")
                self.wfile.flush()
        finally:
            pages.release()

    # ------------------------------------------------------------------------------------------ POST
    def _body(self, action: str) -> dict | None:
        """The request's JSON object, or None after answering 4xx."""
        if self.headers.get_content_type() != "application/json":
            self._error(
                HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "POST a JSON body (Content-Type: application/json)"
            )
            return None
        length = self.headers.get("Content-Length", "0")
        if not length.isdigit() or int(length) > MAX_BODY:
            self._error(HTTPStatus.BAD_REQUEST, f"Content-Length: expected at most {MAX_BODY} bytes")
            return None
        raw = self.rfile.read(int(length))
        try:
            body = json.loads(raw) if raw.strip() else {}
            if not isinstance(body, dict):
                raise ValueError("expected a JSON object")
        except ValueError as exc:
            self._error(HTTPStatus.BAD_REQUEST, f"/api/{action}: the body is not a JSON object ({exc})")
            return None
        return body

    def _post(self) -> None:
        action = urlsplit(self.path).path.removeprefix("/api/")
        if action not in (*EVERY_ACTION, "login", "logout"):
            self._error(HTTPStatus.NOT_FOUND, f"no action {self.path}")
            return
        body = self._body(action)
        if body is None:
            return
        if action in ("login", "logout"):
            self._session(action, body)
            return
        person = self._logged_in()
        if person is None:
            self._audit(None, action, HTTPStatus.UNAUTHORIZED, "refused: not logged in")
            return
        if action not in allowed_to(person.role, self.server.role):
            message = f"role {person.role} may not {action} (docs/security.md: roles)"
            if person.role != self.server.role:
                message += f" on a console whose own role is {self.server.role}"
            self._error(HTTPStatus.FORBIDDEN, message)
            self._audit(person, action, HTTPStatus.FORBIDDEN, "refused: not the role's")
            return
        try:
            reply = self._act(action, body, person)
        except Refused as exc:
            self._error(exc.status, str(exc))
            self._audit(person, action, exc.status, f"refused: {exc}")
            return
        if reply.get("ok"):
            status = HTTPStatus.OK
        elif "no answer" in reply.get("error", ""):
            status = HTTPStatus.BAD_GATEWAY
        else:
            status = HTTPStatus.CONFLICT  # the service or the supervisor said no
        self._json(status, reply)
        said = reply.get("message") or reply.get("error") or _done(reply)
        self._audit(person, action, status, said)

    def _session(self, action: str, body: dict) -> None:
        sessions = self.server.sessions
        if sessions is None:
            self._error(HTTPStatus.NOT_FOUND, "this console has no accounts: nobody logs in")
            return
        secure = "; Secure" if self.server.tls is not None else ""
        if action == "logout":
            person = sessions.logout(self._token())
            forget = f"{COOKIE}=; Path=/; Max-Age=0; HttpOnly; SameSite=Strict{secure}"
            self._json(HTTPStatus.OK, {"ok": True}, {"Set-Cookie": forget})
            if person is not None:
                self._audit(person, "logout", HTTPStatus.OK, "")
            return
        name, password = body.get("name"), body.get("password")
        if not isinstance(name, str) or not isinstance(password, str):
            self._error(HTTPStatus.BAD_REQUEST, '/api/login: expected {"name": NAME, "password": PASSWORD}')
            return
        try:
            token, person = sessions.login(name, password, self.client_address[0], time.monotonic())
        except LoginRefused as exc:
            self._error(exc.status, str(exc))
            self._audit(Person(name[:32], "?"), "login", exc.status, f"refused: {exc}")
            return
        cookie = f"{COOKIE}={token}; Path=/; HttpOnly; SameSite=Strict{secure}"
        self._json(
            HTTPStatus.OK, {"ok": True, "person": person.name, "role": person.role}, {"Set-Cookie": cookie}
        )
        self._audit(person, "login", HTTPStatus.OK, "")

    def _act(self, action: str, body: dict, person: Person) -> dict:
        link = self.server.link
        if action == "start":
            scenario = body.get("scenario")
            if not isinstance(scenario, str):
                raise Refused(HTTPStatus.BAD_REQUEST, '/api/start: expected {"scenario": NAME}')
            return link.start(scenario)
        if action == "stop":
            return link.stop()
        if action == "estop":
            cut = body.get("cut_power", False)
            if not isinstance(cut, bool):
                raise Refused(HTTPStatus.BAD_REQUEST, '/api/estop: "cut_power" is true or false')
            return link.estop("cut_power" if cut else "estop", self._source(person))
        if action == "reset":
            return link.estop("reset", self._source(person))
        if action == "inject":
            return link.inject(body)
        number = body.get("number")
        if number is not None and (type(number) is not int or number < 0):
            raise Refused(HTTPStatus.BAD_REQUEST, '/api/clear: "number" is a fault number >= 0 or null')
        return link.clear(number)


def _done(reply: dict) -> str:
    """An action's answer in a few words, for the audit log."""
    if "state" in reply:
        state = reply["state"] or {}
        return f"supervisor {state.get('state')} ({state.get('reason')}), estop_by {state.get('estop_by')!r}"
    shown = {k: reply[k] for k in ("scenario", "run", "stopping", "fault", "cleared") if k in reply}
    return json.dumps(shown)


def serve(link: RigLink, info: dict, listen: tuple[str, int], tls: ssl.SSLContext | None) -> Console:
    """A started console (its URL in `.url`)."""
    return Console(link, info, listen, tls).start()


__all__ = ["Broadcast", "Console", "ListenError", "parse_listen", "serve", "tls_context"]
