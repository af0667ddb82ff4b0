"""Who may use a console: accounts (a name, one of the bench's roles, an scrypt hash of the password) in a
JSON file kept by `pure-hil accounts`, and the sessions of the people logged in (docs/security.md).

    {"accounts": {"alice": {"role": "operator", "password": "scrypt$16384$8$1$SALT$HASH"}}}

A console given `--accounts FILE` (required to listen beyond loopback) asks each person to log in; the
session is a random token in an HttpOnly, SameSite=Strict cookie, forgotten after IDLE s without a request
or LIFETIME s in all. Failed logins from one address are limited (MAX_FAILURES per FAILURE_WINDOW).
Everything here but the file's reading and writing is pure: the clock is passed in.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import json
import os
import re
import secrets
import stat
import threading
from collections import OrderedDict, deque
from dataclasses import dataclass
from pathlib import Path

from hil.console.roles import PERSON_ROLES

SCRYPT_N, SCRYPT_R, SCRYPT_P = 2**14, 8, 1
"""scrypt's cost (RFC 7914's interactive parameters: ~16 MiB and some 50 ms a check here)."""
MAX_N = 2**20
"""The costliest hash a file may ask for (a tampered file must not make each login take minutes)."""
MIN_PASSWORD = 10
NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,31}")
"""An account's name: it goes into the e-stop's source (at most 64 characters) and the audit log."""
IDLE = 30 * 60.0
"""s without a request after which a session is forgotten."""
LIFETIME = 12 * 3600.0
"""s after a login after which its session is forgotten, however busy."""
MAX_SESSIONS = 256
"""Sessions kept at once: the oldest goes first (memory stays flat whatever logs in)."""
MAX_FAILURES = 5
FAILURE_WINDOW = 60.0
"""At most MAX_FAILURES failed logins from one address within FAILURE_WINDOW s; then 429 until the oldest
ages out."""
MAX_ADDRESSES = 1024
"""Addresses whose failures are remembered (the oldest forgotten first)."""
CHECKS_AT_ONCE = 2
"""scrypt checks running at once (each takes ~16 MiB): a flood of logins queues instead of using memory."""
COOKIE = "pure_hil_console"


class AccountsError(ValueError):
    """The accounts file or an account cannot be used as given: the file, the field and what is expected."""


class LoginRefused(Exception):
    """A login that did not take: its HTTP status and one line saying why."""

    def __init__(self, status: int, message: str):
        super().__init__(message)
        self.status = status


@dataclass(frozen=True, slots=True)
class Account:
    name: str
    role: str
    password: str
    """The scrypt hash: scrypt$N$R$P$SALT$HASH (base64)."""


@dataclass(frozen=True, slots=True)
class Person:
    """Someone logged in: the account's name and role."""

    name: str
    role: str


# ------------------------------------------------------------------------------------------- passwords
def _b64(data: bytes) -> str:
    return base64.b64encode(data).decode()


def hash_password(password: str, n: int = SCRYPT_N) -> str:
    salt = secrets.token_bytes(16)
    digest = hashlib.scrypt(password.encode(), salt=salt, n=n, r=SCRYPT_R, p=SCRYPT_P, maxmem=2**26, dklen=32)
    return f"scrypt${n}${SCRYPT_R}${SCRYPT_P}${_b64(salt)}${_b64(digest)}"


def _parse_hash(encoded: str) -> tuple[int, int, int, bytes, bytes]:
    """(n, r, p, salt, digest); ValueError saying what is wrong."""
    parts = encoded.split("$")
    if len(parts) != 6 or parts[0] != "scrypt":
        raise ValueError("expected scrypt$N$R$P$SALT$HASH (pure-hil accounts add writes it)")
    n, r, p = (int(x) for x in parts[1:4])
    if not (2 <= n <= MAX_N and n & (n - 1) == 0 and 1 <= r <= 32 and 1 <= p <= 16):
        raise ValueError(f"scrypt N={n} r={r} p={p}: N a power of two at most {MAX_N}, r 1..32, p 1..16")
    salt, digest = base64.b64decode(parts[4], validate=True), base64.b64decode(parts[5], validate=True)
    if len(salt) < 16 or len(digest) < 16:
        raise ValueError("salt and hash: at least 16 bytes each")
    return n, r, p, salt, digest


def check_password(password: str, encoded: str) -> bool:
    n, r, p, salt, digest = _parse_hash(encoded)
    maxmem = 2 * 128 * r * n + 2**20
    tried = hashlib.scrypt(password.encode(), salt=salt, n=n, r=r, p=p, maxmem=maxmem, dklen=len(digest))
    return hmac.compare_digest(tried, digest)


# ------------------------------------------------------------------------------------------------ file
def load(path: Path | str) -> dict[str, Account]:
    """The accounts of `path`; AccountsError naming the file, the account and the field."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        text = path.read_text()
    except OSError as exc:
        made = f"make it with: pure-hil accounts add {path} NAME"
        raise AccountsError(f"{path}: {exc.strerror or exc} ({made})") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise AccountsError(
            f"{path} is readable or writable by group or others (mode {stat.S_IMODE(mode):04o}); "
            f"chmod 600 {path}"
        )
    try:
        data = json.loads(text)
    except ValueError as exc:
        raise AccountsError(f"{path}: not JSON ({exc})") from None
    if not isinstance(data, dict) or not isinstance(data.get("accounts"), dict) or set(data) != {"accounts"}:
        raise AccountsError(f'{path}: expected {{"accounts": {{NAME: {{"role": ..., "password": ...}}}}}}')
    accounts = {}
    for name, entry in data["accounts"].items():
        where = f"{path}: accounts.{name}"
        if not NAME.fullmatch(name):
            raise AccountsError(f"{where}: a name is 1-32 letters, digits, '.', '_' or '-', starting alnum")
        if not isinstance(entry, dict) or set(entry) != {"role", "password"}:
            raise AccountsError(f'{where}: expected {{"role": ROLE, "password": HASH}}')
        role, password = entry["role"], entry["password"]
        if role not in PERSON_ROLES:
            raise AccountsError(f"{where}.role: {role!r} is not one of {', '.join(PERSON_ROLES)}")
        try:
            _parse_hash(password if isinstance(password, str) else "")
        except ValueError as exc:
            raise AccountsError(f"{where}.password: {exc}") from None
        accounts[name] = Account(name, role, password)
    if not accounts:
        raise AccountsError(f"{path}: no accounts (add one with: pure-hil accounts add {path} NAME)")
    return accounts


def save(path: Path | str, accounts: dict[str, Account]) -> None:
    """Write the file owner-only, whole or not at all (a temporary file renamed over it)."""
    path = Path(path)
    body = {"accounts": {a.name: {"role": a.role, "password": a.password} for a in accounts.values()}}
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(temporary, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(body, f, indent=2)
            f.write("\n")
        os.replace(temporary, path)
    finally:
        temporary.unlink(missing_ok=True)


def check_new(name: str, role: str, password: str) -> None:
    """AccountsError when an account cannot be made as asked."""
    if not NAME.fullmatch(name):
        raise AccountsError(f"NAME {name!r}: 1-32 letters, digits, '.', '_' or '-', starting alnum")
    if role not in PERSON_ROLES:
        raise AccountsError(f"--role {role!r}: one of {', '.join(PERSON_ROLES)}")
    if len(password) < MIN_PASSWORD:
        raise AccountsError(f"the password: at least {MIN_PASSWORD} characters (got {len(password)})")


# -------------------------------------------------------------------------------------------- sessions
@dataclass(slots=True)
class _Session:
    person: Person
    created: float
    seen: float


class Sessions:
    """The people logged in to one console, by session token (kept as its SHA-256: a lookup never compares
    the secret itself)."""

    def __init__(self, accounts: dict[str, Account]):
        self.accounts = accounts
        self._sessions: OrderedDict[str, _Session] = OrderedDict()
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()  # the console's request threads share the sessions
        self._checks = threading.BoundedSemaphore(CHECKS_AT_ONCE)
        # An unknown name costs the same scrypt as a known one: timing never tells which names exist.
        self._decoy = hash_password(secrets.token_hex(16))

    def login(self, name: str, password: str, address: str, now: float) -> tuple[str, Person]:
        """A new session's token and its person; LoginRefused (401, or 429 when this address failed too
        often lately)."""
        with self._lock:
            failures = self._failures.get(address)
            if failures is not None:
                while failures and now - failures[0] > FAILURE_WINDOW:
                    failures.popleft()
                if len(failures) >= MAX_FAILURES:
                    wait = FAILURE_WINDOW - (now - failures[0])
                    said = f"{len(failures)} failed logins from {address}: wait {wait:.0f} s"
                    raise LoginRefused(429, said)
        account = self.accounts.get(name)
        with self._checks:
            matches = check_password(password, account.password if account else self._decoy)
        with self._lock:
            if account is None or not matches:
                self._failures.setdefault(address, deque()).append(now)
                self._failures.move_to_end(address)
                while len(self._failures) > MAX_ADDRESSES:
                    self._failures.popitem(last=False)
                raise LoginRefused(401, "wrong name or password")
            self._failures.pop(address, None)
            token = secrets.token_urlsafe(32)
            person = Person(account.name, account.role)
            self._expire(now)
            self._sessions[_key(token)] = _Session(person, now, now)
            while len(self._sessions) > MAX_SESSIONS:
                self._sessions.popitem(last=False)
            return token, person

    def person(self, token: str | None, now: float) -> Person | None:
        """Who holds `token` (None: nobody, or the session expired); a request keeps it alive."""
        if not token:
            return None
        key = _key(token)
        with self._lock:
            session = self._sessions.get(key)
            if session is None:
                return None
            if _expired(session, now):
                del self._sessions[key]
                return None
            session.seen = now
            return session.person

    def logout(self, token: str | None) -> Person | None:
        if not token:
            return None
        with self._lock:
            session = self._sessions.pop(_key(token), None)
        return None if session is None else session.person

    def __len__(self) -> int:
        return len(self._sessions)

    def _expire(self, now: float) -> None:
        for key in [k for k, s in self._sessions.items() if _expired(s, now)]:
            del self._sessions[key]


def _expired(session: _Session, now: float) -> bool:
    return now - session.seen > IDLE or now - session.created > LIFETIME


def _key(token: str) -> str:
    return hashlib.sha256(token.encode()).hexdigest()
