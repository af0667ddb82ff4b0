"""`pure-hil console`: the rig's screen in a browser.

In a real headless Chromium (Debian's chromium + chromium-driver, driven by Selenium; skipped, saying why,
where they are missing): `pure-hil serve` and `pure-hil console` as processes, speed_limiting started from the
page, the live speed seen rising with both caps shown, the e-stop pressed in the page and confirmed by the
supervisor without the E-STOP moving, the latch held through the end of the run (Start refused until a reset),
health shown stale once the run ended, the service gone (actions off, E-STOP 502), a different rig on the
endpoint shown and refused, the run still in the history with its new columns; the robot's pose drawn as the
live sample says it (a run released tilted forward and left shows so), greyed once the service goes; and login
by role on an exposed (TLS, accounts) console. Without a browser: the HTTP API's answers to good and bad
requests, the role rules, the pin checked on every action, the latch's state machine, accounts, sessions and
the audit log, the history's columns, no file outside the service's output folder, pages that go away leave no
thread behind, the live pose against the 3-D plant's own body frames on a ride (signs included); and on the
secured bench the router itself refuses a monitor's start and e-stop (the operator's, the positive control,
get through).
"""

from __future__ import annotations

import http.client
import json
import math
import os
import queue
import re
import shutil
import signal
import ssl
import stat
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from datetime import datetime
from pathlib import Path
from types import SimpleNamespace

import msgspec
import numpy as np
import pytest

from drivers.keys import Keys
from drivers.schemas import EstopCommand, SafetyState
from drivers.zenoh_link import ZenohLink, open_session
from hil.bench.bench import load_bench
from hil.bench.certs import init
from hil.commands.serve import STOPPED
from hil.console import accounts, rig_link
from hil.console.events import Broadcast
from hil.console.latch import SILENT, Latch, Word
from hil.console.rig_link import RigLink, fault_catalog
from hil.console.server import Console, ListenError, parse_listen, tls_context
from hil.service import RigService
from tests.helpers import wait_for
from tests.zenoh_helpers import free_port, hub_endpoint, private_bench

BIN = Path(sys.executable).parent
KEYS = Keys()
LONG = """
name = "console_long"
rider = "ref_60kg_180"
duration = 600.0  # lockstep: ended by the test once it has seen what it needs
"""


# -------------------------------------------------------------------------------------------- helpers
class Proc:
    """A pure-hil command as its own process; its output lines are collected as they come."""

    def __init__(self, args: list[str], env: dict):
        self.popen = subprocess.Popen(
            [str(BIN / "pure-hil"), *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.lines: list[str] = []
        self._new: queue.Queue[str] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.popen.stdout:
            self.lines.append(line)
            self._new.put(line)

    def wait_line(self, pattern: str, timeout: float = 30.0) -> re.Match:
        deadline = time.monotonic() + timeout
        for line in self.lines:
            if match := re.search(pattern, line):
                return match
        while time.monotonic() < deadline:
            try:
                line = self._new.get(timeout=max(deadline - time.monotonic(), 0.01))
            except queue.Empty:
                break
            if match := re.search(pattern, line):
                return match
        pytest.fail(f"no line matching {pattern!r} within {timeout} s: {''.join(self.lines)}")

    def stop(self) -> int:
        if self.popen.poll() is None:
            self.popen.send_signal(signal.SIGINT)
            try:
                self.popen.wait(30)
            except subprocess.TimeoutExpired:
                said = "".join(self.lines[-20:])
                print(f"{self.popen.args} did not stop on SIGINT within 30 s: killed. It said:\n{said}")
                self.popen.kill()
                self.popen.wait(10)
        return self.popen.returncode


def _env(tmp_path: Path) -> dict:
    env = {**os.environ, "PURE_HIL_RIGS": str(tmp_path / "rigs"), "OPENBLAS_NUM_THREADS": "1"}
    env.pop("PURE_HIL_HUB", None)
    return env


def request(
    url: str,
    body: dict | bytes | None = None,
    headers: dict | None = None,
    context: ssl.SSLContext | None = None,
    answer: dict | None = None,
) -> tuple[int, object]:
    """(status, JSON body or raw bytes) of a GET, or of a POST of `body`; its headers into `answer`."""
    data = json.dumps(body).encode() if isinstance(body, dict) else body
    sent = {"Content-Type": "application/json"} if isinstance(body, dict) else {}
    req = urllib.request.Request(url, data=data, headers={**sent, **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=30, context=context) as reply:
            status, raw, got = reply.status, reply.read(), reply.headers
    except urllib.error.HTTPError as exc:
        status, raw, got = exc.code, exc.read(), exc.headers
    if answer is not None:
        answer.update(got.items())
    return status, json.loads(raw) if got.get_content_type() == "application/json" else raw


# ------------------------------------------------------------------------------------------ a browser
def chromium(insecure_certs: bool = False):
    """A headless Chromium driven by Selenium through Debian's chromedriver, or a skip saying what is missing.
    Nothing it does leaves the machine: no background networking, updates, sync, QUIC or first-run pings.
    `insecure_certs`: it takes a certificate its own store does not trust (the test's bench CA)."""
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    driver = shutil.which("chromedriver") or "/usr/bin/chromedriver"
    if binary is None or not Path(driver).exists():
        pytest.skip("no Chromium and chromedriver here (apt-get install chromium chromium-driver)")
    webdriver = pytest.importorskip("selenium.webdriver", reason="pip install '.[console-test]' (selenium)")
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = binary
    profile = tempfile.mkdtemp(prefix="pure-hil-chromium-")
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-dev-shm-usage",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-quic",
        "--no-first-run",
        f"--user-data-dir={profile}",
        "--window-size=1400,1150",
    ):
        options.add_argument(flag)
    options.accept_insecure_certs = insecure_certs
    browser = webdriver.Chrome(service=Service(driver), options=options)
    browser.profile_dir = profile
    return browser


def page_wait(browser, script: str, timeout: float = 30.0, what: str = ""):
    """Wait until `script` (returning a value) is truthy in the page; its value."""
    value = wait_for(lambda: browser.execute_script(script), timeout, step=0.05)
    assert value, f"the page never showed {what or script} within {timeout} s"
    return value


def page_message(browser, includes: str, what: str = "") -> str:
    """The page's message line once it includes `includes`."""
    script = f"const m = document.getElementById('message').textContent; return m.includes('{includes}') && m"
    return page_wait(browser, script, what=what)


ESTOP_RECT = "return JSON.stringify(document.getElementById('estop').getBoundingClientRect())"
ROW_1 = "const r = document.querySelector('#history tr[data-run=\"1\"]'); "


def test_the_page_starts_a_run_estops_it_holds_the_latch_and_refuses_a_gone_or_different_rig(tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    browser = chromium()
    env, runs = _env(tmp_path), tmp_path / "runs"
    hub = f"tcp/127.0.0.1:{free_port()}"
    # Lockstep, as the scenario says: a real-time run's embedded controller misses its deadlines on a busy
    # machine and the supervisor stops the robot before the page does. The page reacts within a fraction of a
    # second of wall time, a few tenths of simulated time at this rig's speed, and the e-stop then lands
    # early in the scenario's 7 s of leaning: the robot is stopped and at rest long before its 12 s end.
    serve = Proc(["serve", "--hub", hub, "--out", str(runs)], env)
    console = None
    try:
        serve.wait_line(r"pure-hil serve: bench embedded, hub")
        console = Proc(["console"], env)  # finds the one rig of its bench on this machine
        url = console.wait_line(r"console: (http://127\.0\.0\.1:\d+/)").group(1)
        browser.get(url)
        assert (
            page_wait(browser, "const r = document.getElementById('role').textContent; return r != '?' && r")
            == "operator"
        )
        page_wait(
            browser,
            "return [...document.getElementById('scenario').options].some(o => o.value == 'speed_limiting')",
            what="the scenarios the service offers",
        )
        pid = f"pid {serve.popen.pid}"
        assert pid in browser.find_element(By.ID, "card").text, "the rig it was opened for"
        legend = browser.find_element(By.ID, "legend").text
        assert all(name in legend for name in ("LIMITING", "STOPPING", "ESTOP", "RECOVERY", "SC command cap"))
        Select(browser.find_element(By.ID, "scenario")).select_by_value("speed_limiting")
        estop_at = browser.execute_script(ESTOP_RECT)
        browser.find_element(By.ID, "start").click()
        page_wait(
            browser,
            "return parseFloat(document.getElementById('speed').textContent) > 0.15",
            what="the live speed rising past 0.15 m/s",
        )
        series = browser.execute_script("return window.pureConsole.series")
        speeds = [s["speed"] for s in series]
        assert min(speeds) < 0.05 and max(speeds) > 0.15, f"the live stream showed it rise: {speeds}"
        # Both caps, as plots.png has them: the SC's 0.5 m/s command cap and the supervisor's own.
        assert {s["sc_cap"] for s in series} - {None} == {0.5}, series[-1]
        assert all(s["cap"] > 0.5 for s in series if s["cap"] is not None), series[-1]
        assert browser.find_element(By.ID, "r-sc-cap").text == "±0.50 m/s"
        assert browser.find_element(By.ID, "a-controller").text.endswith("ago"), "fresh while the run goes"

        browser.find_element(By.ID, "estop").click()
        message = page_message(browser, "latched by", what="the supervisor's confirmation")
        assert "OPERATOR_ESTOP" in message and "console operator" in message, message
        banner = browser.find_element(By.ID, "estop-latched")
        assert banner.is_displayed() and banner.text.startswith("E-STOP LATCHED by console operator"), (
            banner.text
        )
        assert browser.execute_script(ESTOP_RECT) == estop_at, "the banner came; the E-STOP stayed put"
        verdict = page_wait(
            browser,
            ROW_1 + "return r && r.children[5].textContent != 'RUNNING' && r.children[5].textContent",
            timeout=60,
            what="the run's end in the history",
        )
        assert verdict == "ESTOPPED"

        # The run ended, and its supervisor with it: the latch is the console's now, and Start is refused.
        held = page_wait(
            browser,
            "const b = document.getElementById('estop-latched').textContent; "
            "return b.includes('NEVER RESET') && b",
            what="the latch held by the console",
        )
        assert "console operator" in held and "run 1" in held, held
        assert browser.find_element(By.ID, "start").get_attribute("disabled")
        status, reply = request(url + "api/start", {"scenario": "bench_smoke"})
        assert status == 409 and "never reset" in reply["error"], reply
        # What the run's health said is shown as it is: stale, with its age.
        for name in ("controller", "drives", "supervisor"):
            assert "stale" in browser.find_element(By.ID, f"h-{name}").get_attribute("class"), name
            assert browser.find_element(By.ID, f"a-{name}").text.startswith("stale"), name
        browser.save_screenshot(str(tmp_path / "console.png"))
        assert (tmp_path / "console.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

        (folder,) = [p for p in runs.iterdir() if p.is_dir()]
        summary = json.loads((folder / "summary.json").read_text())
        steps = [(e["to_state"], e["cause"]) for e in summary["safety"]["events"]]
        assert ("STOPPING", "OPERATOR_ESTOP") in steps, steps
        assert summary["safety"]["ended_resting"] and summary["fallen"] is False
        assert summary["verdict"] == "ESTOPPED"

        browser.find_element(By.ID, "reset").click()
        cleared = page_message(browser, "cleared", what="the reset on the console")
        assert "no supervisor listens" in cleared and "console operator" in cleared, cleared
        page_wait(browser, "return !document.getElementById('start').disabled", what="Start allowed again")
        assert not browser.find_element(By.ID, "estop-latched").is_displayed()
        row = page_wait(browser, ROW_1 + "return r && [...r.children].map(c => c.textContent)", what="run 1")
        assert row[1:3] == ["speed_limiting", "embedded"], row
        assert row[5:9] == ["ESTOPPED", "no", "none", "OPERATOR_ESTOP"], row
        assert all(re.fullmatch(r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d", t) for t in row[10:12]), row

        # The service goes: the page says so, every action but the E-STOP is off, and the E-STOP answers 502.
        assert serve.stop() == STOPPED, "serve stopped by SIGINT exits 130, as run"
        page_wait(
            browser,
            "return document.getElementById('link').textContent.startsWith('service not answering')",
            what="the service gone",
        )
        assert browser.find_element(By.ID, "banner-service").is_displayed()
        assert browser.find_element(By.ID, "start").get_attribute("disabled")
        browser.find_element(By.ID, "estop").click()
        said = page_message(browser, "HTTP")
        assert "(HTTP 502)" in said and "nothing was sent" in said, said

        # Another rig takes the endpoint: shown, and refused, the E-STOP included; the history still reads.
        serve = Proc(["serve", "--bench", "odrive", "--hub", hub, "--out", str(runs)], env)
        serve.wait_line(r"pure-hil serve: bench odrive, hub")
        other = page_wait(
            browser,
            "const b = document.getElementById('banner-rig'); return !b.hidden && b.textContent",
            what="a different rig",
        )
        assert "bench odrive" in other and "bench embedded" in other, other
        assert pid in browser.find_element(By.ID, "card").text, "its own rig, in the header"
        for action, body in (("start", {"scenario": "balance"}), ("estop", {})):
            status, reply = request(url + f"api/{action}", body)
            assert status == 409 and "a different rig answers" in reply["error"], reply
        # One script, not find_element then get_attribute: the page redraws its history as runs change, and
        # an element found before a redraw is stale after it (seen in CI).
        href = page_wait(
            browser,
            'const a = document.querySelector(\'#history tr[data-run="1"] a[href$="plots.png"]\'); '
            "return a && a.href",
            what="run 1's plots link",
        )
        status, png = request(href)
        assert status == 200 and png == (folder / "plots.png").read_bytes()

        # A monitor's console on that rig: the same screen, no button at all.
        watcher = Proc(["console", "--identity", "monitor", "--bench", "odrive"], env)
        try:
            browser.get(watcher.wait_line(r"console: (http://127\.0\.0\.1:\d+/)").group(1))
            page_wait(browser, "return document.getElementById('role').textContent == 'monitor'")
            page_wait(browser, ROW_1 + "return r", what="the history")
            shown = [
                b.get_attribute("id")
                for b in browser.find_elements(By.TAG_NAME, "button")
                if b.is_displayed()
            ]
            assert shown == [], f"a monitor's page shows no action: {shown}"
            assert "may not" in browser.find_element(By.ID, "estop-none").text
        finally:
            watcher.stop()
    finally:
        browser.quit()
        shutil.rmtree(browser.profile_dir, ignore_errors=True)
        if console is not None:
            console.stop()
        serve.stop()


# ------------------------------------------------------------------------------------- the HTTP API
@pytest.fixture
def rig(tmp_path):
    """A service on a loopback hub, and consoles of any role on it (in this process: no browser)."""
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    service = RigService(hub, private_bench(hub=endpoint), out_root=tmp_path / "runs")
    opened = []

    def console(role: str, **options) -> tuple[Console, RigLink]:
        """A console of `role`; `options`: Console's (tls, accounts, audit)."""
        session = open_session(role="member", hub_endpoint=endpoint)
        link = RigLink(session, KEYS, role, f"test {role}", Broadcast())
        info = {"bench": "embedded", "faults": fault_catalog()}
        server = Console(link, info, ("127.0.0.1", 0), **options).start()
        opened.append((server, link, session))
        assert wait_for(lambda: link.status is not None, 10), "the console hears the service"
        return server, link

    yield service, console
    for server, link, session in opened:
        server.close()
        link.close()
        session.close()
    service.close()
    hub.close()


def test_roles_decide_the_actions_and_bad_requests_get_4xx_json(rig, monkeypatch):
    monkeypatch.setattr(rig_link, "CONFIRM_TIMEOUT", 1.0)
    service, console = rig
    operator, _ = console("operator")
    monitor, _ = console("monitor")
    injector, _ = console("fault-injector")
    api = operator.url + "api/"
    for server, actions in (
        (operator, ["estop", "reset", "start", "stop"]),
        (monitor, []),
        (injector, ["clear", "inject"]),
    ):
        status, info = request(server.url + "api/info")
        assert status == 200 and info["role"] == server.role and info["actions"] == actions

    # The role rules, before anything reaches the rig.
    for action, body in (("start", {"scenario": "bench_smoke"}), ("estop", {}), ("inject", {"kind": "x"})):
        status, reply = request(monitor.url + f"api/{action}", body)
        assert (status, reply["ok"]) == (403, False) and "role monitor may not" in reply["error"]
    assert request(injector.url + "api/start", {"scenario": "bench_smoke"})[0] == 403
    assert request(api + "inject", {"kind": "zenoh.wrench_dropout"})[0] == 403

    # Bad requests: one line of JSON each, never a traceback.
    bad = [
        (api + "start", {"scenario": "/etc/passwd"}, 400, "not one the service offers"),
        (api + "start", {"scenario": 3}, 400, "expected"),
        (api + "start", b"{not json", 400, "not a JSON object"),
        (api + "estop", {"cut_power": "yes"}, 400, "cut_power"),
        (injector.url + "api/clear", {"number": -1}, 400, "number"),
        (api + "launch", {}, 404, "no action"),
        (operator.url + "nowhere", None, 404, "nothing at"),
        (api + "history?limit=0", None, 400, "limit"),
        (api + "history?before=x", None, 400, "before"),
        (injector.url + "api/inject", {"kind": "no.such"}, 400, "unknown kind"),
        (injector.url + "api/inject", {"kind": "zenoh.wrench_dropout"}, 409, "no run in progress"),
    ]
    for url, body, want, says in bad:
        headers = {"Content-Type": "application/json"} if isinstance(body, bytes) else None
        status, reply = request(url, body, headers)
        assert status == want and reply["ok"] is False and says in reply["error"], (url, status, reply)
    status, reply = request(api + "start", b"scenario=bench_smoke")  # a form post, as a foreign page sends
    assert status == 415 and "JSON" in reply["error"]
    status, reply = request(api + "info", headers={"Host": "rebound.example:80"})
    assert status == 421 and "answers to" in reply["error"]
    # No run: no supervisor listens, nothing is sent, and that is no answer from the rig (docs/rig.md: 502).
    for action in ("estop", "reset"):
        status, reply = request(api + action, {})
        assert status == 502 and "no supervisor listens" in reply["error"], (action, reply)

    # A run, then its files: only plain files of its folder, in as many chunks as it takes.
    monkeypatch.setattr("hil.service.CHUNK", 1000)
    status, reply = request(api + "start", {"scenario": "bench_smoke"})
    assert status == 200 and reply["run"] == 1
    assert service.wait_idle(60) and wait_for(lambda: service.history.runs()[0]["verdict"] != "RUNNING")
    status, history = request(api + "history?limit=5")
    (run,) = history["runs"]
    assert (run["scenario"], run["verdict"], run["controller"]) == (
        "bench_smoke",
        "PASSED",
        "embedded reference hacs",
    )
    assert (run["fallen"], run["fall_cause"], run["faults"]) == (False, None, [])
    folder = service.history.folder / run["folder"]
    assert {"summary.json", "plots.png", "recording.rrd"} <= set(run["files"])
    summary = (folder / "summary.json").read_bytes()
    assert len(summary) > 3000, "several chunks"
    assert request(operator.url + "runs/1/summary.json") == (200, json.loads(summary))
    assert request(monitor.url + "runs/1/plots.png") == (200, (folder / "plots.png").read_bytes())

    outside = service.history.folder.parent / "secret.txt"
    outside.write_text("not for the console")
    (folder / "link.txt").symlink_to(outside)
    (service.history.folder / "top.txt").write_text("the output folder itself is not a run folder")
    for path in (
        "runs/1/..%2F..%2Fsecret.txt",
        "runs/1/../../secret.txt",
        "runs/1/%2E%2E",
        "runs/1/link.txt",
        "runs/1/..%2Ftop.txt",
        "runs/1/..%2Fhistory.sqlite",
        "runs/2/summary.json",
        "runs/1/.x",
        "runs/1/",
        "runs/-1/summary.json",
        "runs/1/summary.json/x",
    ):
        status, reply = request(operator.url + path)
        assert status == 404 and reply["ok"] is False, (path, status, reply)
    # The service itself refuses it too, to any client of the hub.
    client = open_session(role="member", hub_endpoint=service.bench.zenoh.endpoint)
    try:
        for name in ("../secret.txt", "link.txt", "/etc/passwd", "../history.sqlite"):
            asked = json.dumps({"run": 1, "name": name})
            (reply,) = list(client.get(KEYS.rig_file, payload=asked, timeout=10))
            assert reply.ok is None and not json.loads(reply.err.payload.to_string())["ok"], name
    finally:
        client.close()


def test_pages_that_go_away_leave_no_thread_behind(rig):
    _, console = rig
    server, _ = console("monitor")
    baseline = threading.active_count()
    pages = []
    for _ in range(5):
        page = http.client.HTTPConnection("127.0.0.1", server.server_address[1], timeout=10)
        page.request("GET", "/api/events")
        reply = page.getresponse()
        assert reply.status == 200 and reply.headers.get_content_type() == "text/event-stream"
        assert reply.read1(65536).startswith(b"retry: 1000")
        pages.append((page, reply))
    # Positive control: the count sees the open pages' threads.
    assert threading.active_count() >= baseline + 5
    for page, reply in pages:
        reply.close()
        page.close()
    assert wait_for(lambda: threading.active_count() <= baseline, 15), (threading.active_count(), baseline)


class _CannedLink(RigLink):
    """A RigLink without zenoh: its questions to the service get the given answers in turn."""

    def __init__(self, *answers: dict, pinned: dict | None = None):
        self._answers = iter(answers)
        self.keys, self.role, self.source = KEYS, "operator", "test"
        self.clock = time.monotonic
        self.pinned, self.card, self.status, self.answered, self.run = pinned, None, None, None, None
        self.latch = Latch()
        self._lock = threading.Lock()
        self.asked: list[str] = []

    def ask(self, name: str, payload: str = "", timeout: float = 0.0) -> dict:
        self.asked.append(name)
        return next(self._answers)


CARD = {"bench": "lab", "endpoint": "tcp/127.0.0.1:1", "pid": 10, "runs": "serve", "started": 0.0, "id": "a1"}
NO_ANSWER = {"ok": False, "error": "no answer on pure/rig/status"}


def _status(card: dict, **more) -> dict:
    return {"ok": True, "state": "idle", "run": None, "card": card, "scenarios": ["balance"], **more}


def test_every_action_checks_the_rig_first_and_sends_nothing_to_another_or_to_none():
    """The pin, action by action: the console's own rig (positive control), the same bench and pid with
    another id (a restart that got its pid back), another bench, and no answer at all."""
    same = _status(CARD)
    restarted = _status({**CARD, "id": "b2"})
    other = _status({**CARD, "bench": "odrive", "pid": 11, "id": "c3"})
    acts = {
        "start": lambda link: link.start("balance"),
        "stop": lambda link: link.stop(),
        "inject": lambda link: link.inject({"kind": "zenoh.wrench_dropout"}),
        "clear": lambda link: link.clear(None),
        "estop": lambda link: link.estop("estop"),
        "reset": lambda link: link.estop("reset"),
    }
    for name, act in acts.items():
        if name not in ("estop", "reset"):  # those need a zenoh session past the check: below, for real
            link = _CannedLink(same, {"ok": True, "went": name}, pinned=CARD)
            assert act(link) == {"ok": True, "went": name}, name
        for answer, status, says in (
            (restarted, 409, "a different rig answers"),
            (other, 409, "bench odrive"),
            (NO_ANSWER, 502, "no answer from the rig this console was opened for"),
        ):
            link = _CannedLink(answer, pinned=CARD)
            with pytest.raises(rig_link.Refused, match=says) as refused:
                act(link)
            assert refused.value.status == status and link.asked == ["status"], (name, link.asked)
    # A console that was told no card (a router hides them) pins to the first rig it hears.
    link = _CannedLink(same, {"ok": True}, other)
    assert link.stop() == {"ok": True} and link.pinned == CARD
    with pytest.raises(rig_link.Refused, match="a different rig"):
        link.stop()


def test_a_fault_is_refused_on_a_rider_bench_by_the_status_asked_with_it():
    link = _CannedLink(_status(CARD, bench={"name": "lab", "rider_on_board": True}), pinned=CARD)
    with pytest.raises(rig_link.Refused, match="bench lab says a person is on the robot") as refused:
        link.inject({"kind": "zenoh.wrench_dropout"})
    assert refused.value.status == 409 and link.asked == ["status"]


def test_a_start_is_refused_while_an_estop_is_latched():
    link = _CannedLink(_status(CARD), _status(CARD), {"ok": True, "scenario": "balance"}, pinned=CARD)
    link.latch.heard(Word("ESTOP", "OPERATOR_ESTOP", "console operator alice", 1, link.clock()))
    with pytest.raises(rig_link.Refused, match="the supervisor holds an e-stop by console operator alice"):
        link.start("balance")
    link.latch.reset()
    assert link.start("balance")["ok"], "the positive control: once reset, it starts"


def test_a_file_answer_without_its_size_is_a_bad_gateway():
    link = _CannedLink()
    answer = SimpleNamespace(ok=SimpleNamespace(attachment=None, payload=None), err=None)
    link.session = SimpleNamespace(get=lambda *args, **kwargs: [answer])
    with pytest.raises(rig_link.Refused, match="does not say the file's size") as refused:
        link.file(1, "summary.json")
    assert refused.value.status == 502


def test_a_console_is_pinned_to_its_rig_and_refuses_the_next_one_on_the_endpoint(rig, tmp_path):
    """In this process: the service the console was opened for answers (positive control), then another
    service on the same hub, in the same process (the same pid, a new id), then none."""
    service, console = rig
    server, link = console("operator")
    api = server.url + "api/"
    status, info = request(api + "info")
    assert info["card"]["id"] == service.card.id and info["card"]["pid"] == os.getpid()
    assert request(api + "stop", {}) == (200, {"ok": True, "stopping": False})
    service.close()
    service.close = lambda: None  # closed here; the fixture's close has nothing left to do
    after = RigService(service.session, service.bench, out_root=tmp_path / "runs")
    try:
        assert wait_for(lambda: link.card and link.card["id"] == after.card.id, 10)
        for action, body in (("start", {"scenario": "balance"}), ("stop", {}), ("estop", {}), ("reset", {})):
            status, reply = request(api + action, body)
            assert status == 409 and after.card.id in reply["error"] and service.card.id in reply["error"]
        assert after.state == "idle", "nothing reached the other rig"
        events = server.link.events.latest("status")
        assert events is not None and b'"rig": "different"' in events
    finally:
        after.close()
    for action in ("stop", "estop"):
        status, reply = request(api + action, {})
        assert status == 502 and "nothing was sent" in reply["error"], reply


def test_listen_and_tls_options(tmp_path):
    assert parse_listen("127.0.0.1:0") == ("127.0.0.1", 0) and parse_listen("[::1]:8080") == ("::1", 8080)
    for text in ("localhost:80", "127.0.0.1", "127.0.0.1:70000", "1.2.3.4:x"):
        with pytest.raises(ListenError, match="--listen"):
            parse_listen(text)
    with pytest.raises(ListenError, match="go together"):
        tls_context(str(tmp_path / "c.pem"), None)
    with pytest.raises(ListenError, match="cannot load"):
        tls_context(str(tmp_path / "c.pem"), str(tmp_path / "k.pem"))
    with pytest.raises(ListenError, match="not loopback: give --tls-cert"):
        Console(None, {}, ("0.0.0.0", 0))  # type: ignore[arg-type]
    init(tmp_path / "certs")
    tls = tls_context(str(tmp_path / "certs/router.pem"), str(tmp_path / "certs/router.key"))
    with pytest.raises(ListenError, match="not loopback: give --accounts FILE"):
        Console(None, {}, ("0.0.0.0", 0), tls)  # type: ignore[arg-type]
    from hil.cli import main

    for args, says in ((["--listen", "0.0.0.0:0"], "--tls-cert"), (["--listen", "nope"], "--listen")):
        proc = subprocess.run(
            [str(BIN / "pure-hil"), "console", *args],
            capture_output=True,
            text=True,
            env=_env(tmp_path),
            timeout=60,
        )
        assert proc.returncode == 2 and says in proc.stderr and len(proc.stderr.splitlines()) == 1, (
            proc.stderr
        )
    assert main(["console", "--tls-key", "k.pem"]) == 2
    cert, key = str(tmp_path / "certs/router.pem"), str(tmp_path / "certs/router.key")
    tls_options = ["--tls-cert", cert, "--tls-key", key]
    assert main(["console", "--listen", "0.0.0.0:0", *tls_options]) == 2
    assert main(["console", "--accounts", str(tmp_path / "nobody.json")]) == 2


def test_https_console_with_the_bench_certificates(rig, tmp_path):
    """--tls-cert/--tls-key: the page over HTTPS (here with the bench CA's router certificate)."""
    service, _ = rig
    certs = tmp_path / "certs"
    init(certs)
    session = open_session(role="member", hub_endpoint=service.bench.zenoh.endpoint)
    link = RigLink(session, KEYS, "monitor", "test", Broadcast())
    tls = tls_context(str(certs / "router.pem"), str(certs / "router.key"))
    server = Console(link, {"card": None, "bench": "embedded", "faults": []}, ("127.0.0.1", 0), tls).start()
    try:
        assert server.url.startswith("https://127.0.0.1:")
        trusted = ssl.create_default_context(cafile=str(certs / "ca.pem"))
        with urllib.request.urlopen(server.url + "api/info", context=trusted, timeout=10) as reply:
            assert json.loads(reply.read())["role"] == "monitor"
        with pytest.raises(urllib.error.URLError, match="CERTIFICATE_VERIFY_FAILED"):
            urllib.request.urlopen(server.url, context=ssl.create_default_context(), timeout=10)
    finally:
        server.close()
        link.close()
        session.close()


# --------------------------------------------------------------------------------- the secured bench
@pytest.fixture
def router(tmp_path):
    certs = tmp_path / "certs"
    init(certs)
    endpoint = f"tls/127.0.0.1:{free_port()}"
    proc = Proc(["router", "--certs", str(certs), "--listen", endpoint], _env(tmp_path))
    try:
        proc.wait_line("pure-hil router:")
        yield endpoint, certs
    finally:
        proc.stop()


def test_on_the_secured_bench_the_router_refuses_a_monitors_start_and_estop(router, tmp_path, monkeypatch):
    endpoint, certs = router
    monkeypatch.setattr(rig_link, "CONFIRM_TIMEOUT", 2.0)
    bench = load_bench("secured").with_overrides(hub=endpoint, certs=str(certs))
    rig_session = bench.zenoh.open("rig")
    service = RigService(rig_session, bench, out_root=tmp_path / "runs")
    sessions = {role: bench.zenoh.open(role) for role in ("operator", "monitor", "fault-injector")}
    links = {role: RigLink(s, KEYS, role, f"console {role}", Broadcast()) for role, s in sessions.items()}
    states: list[SafetyState] = []
    witness = ZenohLink(sessions["operator"]).subscribe(KEYS.safety_state, SafetyState, capacity=4096)
    try:
        assert wait_for(lambda: all(link.status for link in links.values()), 15), (
            "every role reads the status"
        )
        monitor, operator = links["monitor"], links["operator"]
        # The monitor's start goes unanswered (the ACL drops it); the operator's runs (positive control).
        assert "no answer" in monitor.ask("start", LONG, timeout=2.0)["error"]
        assert service.state == "idle"
        assert operator.ask("start", LONG)["ok"]
        assert wait_for(lambda: service.sim_time > 0.5, 30)
        # The monitor's e-stop: refused by its console's own route (the router shows it no supervisor), and
        # its raw puts on the e-stop key never reach the supervisor.
        reply = monitor_estop = None
        try:
            monitor_estop = monitor.estop("estop")
        except rig_link.Refused as exc:
            reply = str(exc)
        assert reply is not None or not monitor_estop["confirmed"], (reply, monitor_estop)
        raw = ZenohLink(sessions["monitor"])
        for seq in range(10):
            raw.put(
                KEYS.safety_estop, EstopCommand(seq=seq, stamp=0.0, action="estop", source="console monitor")
            )
        # Ten more of the supervisor's states (1 s of the run) after the puts: they had time to arrive.
        seen = len(witness.drain())
        assert wait_for(lambda: (states.extend(witness.drain()), len(states) >= 10)[1], 15)
        assert seen and not any(s.estop_by for s in states), "the monitor's e-stop reached nobody"
        # The fault-injector's console refuses faults on a bench with a rider on board.
        with pytest.raises(rig_link.Refused, match="a person is on the robot"):
            links["fault-injector"].inject({"kind": "zenoh.wrench_dropout"})
        # Positive control: the operator's e-stop, through the same router, is confirmed by the supervisor.
        confirmed = operator.estop("estop")
        assert confirmed["confirmed"] and confirmed["state"]["estop_by"] == "console operator"
        assert operator.stop()["ok"]
        assert service.wait_idle(60)
        # Every role reads the history and the runs' files (an error reply crosses the router too).
        history = monitor.history(5, None)
        assert history["ok"] and history["runs"][0]["first_cause"] == "OPERATOR_ESTOP"
        size, chunks = monitor.file(1, "summary.json")
        assert size > 1000
        assert json.loads(b"".join(chunks))["safety"]["events"][0]["cause"] == "OPERATOR_ESTOP"
        with pytest.raises(rig_link.Refused, match="not a plain file name"):
            monitor.file(1, "../history.sqlite")
    finally:
        witness.close()
        for link in links.values():
            link.close()
        for s in sessions.values():
            s.close()
        service.close()
        rig_session.close()


# ------------------------------------------------------------------------------------ the e-stop latch
def _word(at: float, estop_by: str = "", state: str = "NORMAL", run: int | None = 1) -> Word:
    return Word(state, "OPERATOR_ESTOP" if estop_by else "START", estop_by, run, at)


def test_the_latch_follows_the_supervisor_while_it_speaks():
    latch = Latch()
    assert latch.view(0.0)["latched"] is None and latch.start_refusal(0.0) == ""
    latch.heard(_word(0.0))
    assert latch.holder(0.1) is None and latch.start_refusal(0.1) == "", "positive control: nothing latched"
    latch.heard(_word(1.0, "console operator alice", "STOPPING"))
    assert latch.holder(1.1) == "supervisor"
    assert "the supervisor holds an e-stop by console operator alice" in latch.start_refusal(1.1)
    latch.heard(_word(1.5, "console operator alice", "ESTOP"))
    assert latch.held is not None and latch.held.since == 1.0, "the same latch, first heard at 1.0"
    latch.heard(_word(2.0))  # the supervisor's own word that a reset took
    assert latch.held is None and latch.start_refusal(2.0) == ""


def test_a_latch_whose_supervisor_goes_is_held_by_the_console_until_a_reset():
    latch = Latch()
    latch.heard(_word(1.0, "console operator alice", "ESTOP"))
    assert latch.holder(1.0 + SILENT) == "supervisor" and latch.holder(1.01 + SILENT) == "console"
    view = latch.view(10.0)
    assert (
        view["silent"]
        and view["latched"]["held_by"] == "console"
        and "silent for 9 s" in view["latched"]["why"]
    )
    assert "never reset" in latch.start_refusal(10.0) and "press Reset" in latch.start_refusal(10.0)
    # The next run's supervisor starts NORMAL: it never saw that e-stop, so the console keeps it.
    latch.heard(_word(11.0, run=2))
    assert latch.holder(11.0) == "console" and latch.start_refusal(11.0)
    assert latch.reset() is not None and latch.start_refusal(11.0) == "" and latch.reset() is None


def test_a_new_runs_supervisor_within_the_silence_never_clears_the_last_runs_latch():
    latch = Latch()
    latch.heard(_word(1.0, "console operator alice", "ESTOP", run=1))
    latch.heard(_word(1.5, run=2))  # within SILENT, but another run's supervisor
    assert latch.holder(1.5) == "console" and "run 2's never saw it" in latch.view(1.5)["latched"]["why"]


def test_a_supervisor_that_comes_back_latched_holds_it_again():
    latch = Latch()
    latch.heard(_word(1.0, "console operator alice", "ESTOP"))
    latch.heard(_word(5.0, "console operator alice", "ESTOP"))  # after a silence, still latched
    assert latch.holder(5.0) == "supervisor" and latch.held is not None and latch.held.since == 1.0
    latch.heard(_word(5.5))
    assert latch.held is None, "and its reset clears it"


def test_a_run_that_ended_estopped_before_the_console_heard_it_is_held():
    latch = Latch()
    latch.run_ended(3, "PASSED", 1.0)
    assert latch.held is None, "positive control: not every end is an e-stop"
    latch.run_ended(3, "ESTOPPED", 1.0)
    assert latch.holder(1.0) == "console" and "ended ESTOPPED" in latch.start_refusal(1.0)
    heard = Latch()
    heard.heard(_word(0.5, run=4))
    heard.run_ended(4, "ESTOPPED", 1.0)  # heard that run: its reset (NORMAL) is known
    assert heard.held is None


# --------------------------------------------------------------------------------- the live stream
def test_the_live_stream_gives_signed_speed_and_tilt_and_the_sc_cap():
    from drivers.schemas import ScCommand
    from hil.live import LiveStream

    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    stream = LiveStream(hub, KEYS)
    motors = [SimpleNamespace(permitted=True)] * 3
    drives = SimpleNamespace(motors=motors, contactor_closed=True)

    def plant(forward: float, pitch: float):
        truth = SimpleNamespace(
            t=1.0, velocity=(forward, 0.4), tilt=(pitch, 0.0), lean=(0.1, 0.0), powered=True, resting=False,
            fallen=None, yaw=0.0, position=(0.0, 0.0),
        )  # fmt: skip
        return SimpleNamespace(truth=lambda: truth, drives=drives)

    sc = ZenohLink(hub)
    try:
        backwards = stream.sample(plant(-0.95, -0.05))
        assert backwards["speed"] == -0.95 and backwards["tilt_deg"] < 0, "signed, as plots.png draws them"
        assert stream.sample(plant(0.95, 0.05))["speed"] == 0.95, "positive control"
        sc.put(KEYS.sc_command, ScCommand(seq=1, stamp=0.0, mode="limit", speed_cap=0.5, source="sc"))
        assert wait_for(lambda: stream.sample(plant(0.1, 0.0))["sc_cap"] == 0.5, 5)
        sc.put(KEYS.sc_command, ScCommand(seq=2, stamp=0.0, mode="free", source="sc"))
        assert wait_for(lambda: stream.sample(plant(0.1, 0.0))["sc_mode"] == "free", 5)
        assert stream.sample(plant(0.1, 0.0))["sc_cap"] is None, "no cap out of limit mode"
    finally:
        sc.close()
        stream.close()
        hub.close()


def _axes(quaternion) -> np.ndarray:
    """A body's rotation matrix (columns: its x, y, z axes in the world) from MuJoCo's (w, x, y, z)."""
    w, x, y, z = quaternion
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _seen(poses: dict, body: str) -> tuple[float, float, float]:
    """Where `body`'s z axis points, read off the bodies' world poses alone (not the plant's Euler angles):
    (pitch: its top forward, roll: its top to the right, in the chassis' heading frame; heading: the chassis'
    x axis from the world's x, counter-clockwise), degrees."""
    chassis_x = _axes(poses["chassis"][1])[:, 0]
    heading = math.atan2(chassis_x[1], chassis_x[0])
    up = _axes(poses[body][1])[:, 2]
    forward = math.cos(heading) * up[0] + math.sin(heading) * up[1]
    left = -math.sin(heading) * up[0] + math.cos(heading) * up[1]
    pitch, roll = math.atan2(forward, up[2]), math.asin(-left)  # up = (sin p cos r, -sin r, cos p cos r)
    return math.degrees(pitch), math.degrees(roll), math.degrees(heading)


def test_the_live_pose_is_the_bodies_pose_on_a_ride_signs_included():
    """The live sample's pose against the 3-D plant's own bodies (plant.poses(): MuJoCo's frames) on a ride
    released tilted forward and to the right, then turning more than half a circle while the rider leans
    forward and sways: chassis tilt, heading and the ball's place exactly, the torso (tilt + lean) within a
    degree."""
    from hil.live import LiveStream
    from hil.run.truth_balancer import TruthBalancer
    from plant.ballbot3d import Plant3D
    from plant.core import RiderIntent
    from plant.rider import Hold, Ramp, Sine
    from tests.helpers import RIDER_75, robot, sim

    intent = RiderIntent(
        pitch=[Hold(duration=0.5), Ramp(to=10.0, duration=1.0), Hold(duration=2.0)],
        roll=[Hold(duration=1.0), Sine(amplitude=8.0, frequency_hz=0.5, duration=3.0)],
    )
    plant = Plant3D(robot(), RIDER_75, sim(plant="3d"), intent, (math.radians(4.0), math.radians(3.0)))
    endpoint = hub_endpoint()
    hub = open_session(role="hub", hub_endpoint=endpoint)
    stream = LiveStream(hub, KEYS)
    try:
        start = stream.sample(plant)["pose"]
        assert start["tilt_deg"] == [4.0, 3.0] and start["heading_deg"] == 0.0, start
        top = _axes(plant.poses()["chassis"][1])[:, 2]
        assert top[0] > 0.05 and top[1] < -0.04, f"released forward (+x) and to the right (-y): {top}"
        balancer = TruthBalancer(plant)
        balancer.yaw_rate_command = 0.8
        seen = []
        for tick in range(1600):  # 4 s: up to 1.2 m/s, 0.8 rad/s
            balancer.set_velocity(1.2 * min(1.0, tick / 400))
            balancer.drive()
            plant.step()
            if tick % 40 == 39:
                sample, poses = stream.sample(plant)["pose"], plant.poses()
                pitch, roll, heading = _seen(poses, "chassis")
                assert sample["tilt_deg"] == pytest.approx([pitch, roll], abs=0.002), (plant.t, sample)
                assert -180.0 <= sample["heading_deg"] < 180.0
                assert (sample["heading_deg"] - heading + 180.0) % 360.0 - 180.0 == pytest.approx(0, abs=0.01)
                assert sample["position"] == pytest.approx(poses["ball"][0][:2], abs=1e-4), (plant.t, sample)
                torso = _seen(poses, "torso")[:2]
                drawn = [t + lean for t, lean in zip(sample["tilt_deg"], sample["lean_deg"], strict=True)]
                assert drawn == pytest.approx(torso, abs=1.0), (plant.t, sample, torso)
                seen.append(sample)
        assert plant.fallen is None
        leans = np.array([s["lean_deg"] for s in seen])
        assert leans[:, 0].max() > 8.0 and leans[:, 1].min() < -5.0 < 5.0 < leans[:, 1].max(), leans
        headings = [s["heading_deg"] for s in seen]
        assert min(headings) < -90.0 and max(headings) > 150.0, f"past half a circle, wrapped: {headings}"
    finally:
        stream.close()
        hub.close()


# ------------------------------------------------------------------------------- accounts and login
FAST = 2**10
"""scrypt's N for the tests' own accounts (a login still checks what the file says)."""


def _accounts(path: Path, **people: str) -> dict[str, accounts.Account]:
    """An accounts file of name=role, each password 'NAME-password'."""
    made = {
        name: accounts.Account(name, role, accounts.hash_password(f"{name}-password", n=FAST))
        for name, role in people.items()
    }
    accounts.save(path, made)
    return made


def test_the_accounts_command_keeps_hashes_owner_only_and_bad_files_say_what(tmp_path, monkeypatch, capsys):
    import io

    from hil.cli import main

    path = tmp_path / "people.json"
    monkeypatch.setattr("sys.stdin", io.StringIO("correct horse battery\n"))
    assert main(["accounts", "add", str(path), "alice", "--role", "operator"]) == 0
    assert stat.S_IMODE(path.stat().st_mode) == 0o600 and "correct horse" not in path.read_text()
    (alice,) = accounts.load(path).values()
    assert (alice.name, alice.role) == ("alice", "operator")
    assert alice.password.startswith("scrypt$16384$8$1$")
    assert accounts.check_password("correct horse battery", alice.password)
    assert not accounts.check_password("correct horse batterx", alice.password), "positive control"
    monkeypatch.setattr("sys.stdin", io.StringIO("short\n"))
    assert main(["accounts", "add", str(path), "bob"]) == 2
    assert "at least 10 characters" in capsys.readouterr().err
    assert main(["accounts", "list", str(path)]) == 0 and capsys.readouterr().out == "alice\toperator\n"
    assert main(["accounts", "remove", str(path), "alice"]) == 2, "the last account stays"

    good = json.loads(path.read_text())
    bad = [
        (good, 0o644, "readable or writable by group or others (mode 0644); chmod 600"),
        ("{", 0o600, "not JSON"),
        ({"accounts": {}}, 0o600, "no accounts"),
        ({"accounts": {"al ice": good["accounts"]["alice"]}}, 0o600, "accounts.al ice: a name is"),
        ({"accounts": {"alice": {**good["accounts"]["alice"], "role": "root"}}}, 0o600, "alice.role: 'root'"),
        ({"accounts": {"alice": {"role": "monitor", "password": "hunter2"}}}, 0o600, "alice.password"),
        (
            {"accounts": {"alice": {"role": "monitor", "password": "scrypt$1048577$8$1$AAAA$AAAA"}}},
            0o600,
            "power of two at most",
        ),
    ]
    for content, mode, says in bad:
        path.write_text(content if isinstance(content, str) else json.dumps(content))
        path.chmod(mode)
        with pytest.raises(accounts.AccountsError, match=re.escape(says)):
            accounts.load(path)


def test_sessions_expire_stay_bounded_and_failed_logins_are_limited(monkeypatch):
    people = {
        name: accounts.Account(name, "operator", accounts.hash_password(f"{name}-password", n=FAST))
        for name in ("alice", "bob", "carol", "dave")
    }
    sessions = accounts.Sessions(people)
    token, person = sessions.login("alice", "alice-password", "10.0.0.1", 0.0)
    assert person == accounts.Person("alice", "operator") and sessions.person(token, 1.0) == person
    assert sessions.person("forged", 1.0) is None and sessions.person(None, 1.0) is None
    assert sessions.person(token, 1.0 + accounts.IDLE) == person, "each request keeps it alive"
    assert sessions.person(token, 2.0 + 2 * accounts.IDLE) is None, "idle too long"
    token, _ = sessions.login("alice", "alice-password", "10.0.0.1", 0.0)
    for seen in range(1200, int(accounts.LIFETIME), 1200):  # a request every 20 min keeps it alive ...
        assert sessions.person(token, float(seen)) is not None, seen
    assert sessions.person(token, accounts.LIFETIME + 1.0) is None, "and never beyond its lifetime"
    token, _ = sessions.login("bob", "bob-password", "10.0.0.1", 0.0)
    assert sessions.logout(token) == accounts.Person("bob", "operator")
    assert sessions.person(token, 0.0) is None

    for name in ("alice", "nobody"):
        with pytest.raises(accounts.LoginRefused, match="wrong name or password") as refused:
            sessions.login(name, "guess", "10.0.0.2", 0.0)
        assert refused.value.status == 401
    for _ in range(accounts.MAX_FAILURES - 2):
        with pytest.raises(accounts.LoginRefused):
            sessions.login("alice", "guess", "10.0.0.2", 1.0)
    with pytest.raises(accounts.LoginRefused, match=r"5 failed logins from 10\.0\.0\.2") as refused:
        sessions.login("alice", "alice-password", "10.0.0.2", 2.0)  # the right password, too late
    assert refused.value.status == 429
    assert sessions.login("alice", "alice-password", "10.0.0.3", 2.0), "another address is not held up"
    assert sessions.login("alice", "alice-password", "10.0.0.2", 2.0 + accounts.FAILURE_WINDOW)

    monkeypatch.setattr(accounts, "MAX_SESSIONS", 3)
    tokens = [sessions.login(n, f"{n}-password", "10.0.0.4", 10.0)[0] for n in people]
    assert len(sessions) == 3 and sessions.person(tokens[0], 10.0) is None
    assert sessions.person(tokens[3], 10.0) is not None


def test_an_exposed_console_asks_each_person_to_log_in_and_logs_who_did_what(rig, tmp_path):
    _, console = rig
    init(tmp_path / "certs")
    tls = tls_context(str(tmp_path / "certs/router.pem"), str(tmp_path / "certs/router.key"))
    trusted = ssl.create_default_context(cafile=str(tmp_path / "certs/ca.pem"))
    people = _accounts(tmp_path / "people.json", alice="operator", bob="monitor", fay="fault-injector")
    audit: list[str] = []
    server, _ = console("operator", tls=tls, accounts=people, audit=audit.append)
    url = server.url

    def ask(path: str, body=None, cookie: str = "", answer: dict | None = None):
        headers = {"Cookie": cookie} if cookie else None
        return request(url + path, body, headers, trusted, answer)

    def log_in(name: str) -> str:
        answer: dict = {}
        status, reply = ask("api/login", {"name": name, "password": f"{name}-password"}, answer=answer)
        assert status == 200 and reply["person"] == name, reply
        flags = answer["Set-Cookie"]
        assert all(flag in flags for flag in ("HttpOnly", "SameSite=Strict", "Secure", "Path=/")), flags
        return flags.split(";")[0]

    assert ask("")[0] == 200, "the page (its login form) is served to anyone"
    for path, body in (
        ("api/info", None),
        ("api/events", None),
        ("runs/1/summary.json", None),
        ("api/estop", {}),
    ):
        status, reply = ask(path, body)
        assert (status, reply["login"]) == (401, True), path
    assert ask("api/estop", {}, cookie=f"{accounts.COOKIE}=forged")[0] == 401
    status, reply = ask("api/login", {"name": "alice", "password": "guess"})
    assert status == 401 and reply["error"] == "wrong name or password"
    forged = "x\nconsole audit 2026-01-01T00:00:00+00:00 alice (operator) from 127.0.0.1: estop -> 200"
    assert ask("api/login", {"name": forged, "password": "guess"})[0] == 401

    bob = log_in("bob")
    status, info = ask("api/info", cookie=bob)
    assert (info["person"], info["role"], info["actions"]) == ("bob", "monitor", [])
    assert ask("api/estop", {}, cookie=bob)[0] == 403
    fay = log_in("fay")  # a fault-injector on an operator's console: never more than the console's role
    assert ask("api/info", cookie=fay)[1]["actions"] == []
    alice = log_in("alice")
    status, info = ask("api/info", cookie=alice)
    assert info["actions"] == ["estop", "reset", "start", "stop"]
    assert info["source"] == "console operator alice", "its e-stops name the person"
    status, reply = ask("api/estop", {}, cookie=alice)
    assert status == 502 and "no supervisor listens" in reply["error"]
    assert ask("api/logout", {}, cookie=alice) == (200, {"ok": True})
    assert ask("api/info", cookie=alice)[0] == 401, "logged out"

    said = "\n".join(audit)
    for line in (
        "(not logged in) from 127.0.0.1: estop -> 401",
        "alice (?) from 127.0.0.1: login -> 401 refused: wrong name or password",
        "bob (monitor) from 127.0.0.1: login -> 200",
        "bob (monitor) from 127.0.0.1: estop -> 403 refused: not the role's",
        "alice (operator) from 127.0.0.1: estop -> 502 refused: no supervisor listens",
        "alice (operator) from 127.0.0.1: logout -> 200",
    ):
        assert line in said, f"{line!r} not in the audit log:\n{said}"
    assert all(re.match(r"console audit \d{4}-\d\d-\d\dT\d\d:\d\d:\d\d", a) for a in audit)
    assert all("\n" not in a for a in audit), "a name typed at the login stays on its line"
    assert "x\\nconsole audit 2026" in said


def test_in_the_browser_each_person_logs_in_and_acts_with_their_role(rig, tmp_path):
    """An exposed console (TLS, accounts): the login form, a wrong password, a monitor who sees no action,
    and an operator whose E-STOP the supervisor records under their name; each in the audit log."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    service, console = rig
    init(tmp_path / "certs")
    tls = tls_context(str(tmp_path / "certs/router.pem"), str(tmp_path / "certs/router.key"))
    people = _accounts(tmp_path / "people.json", alice="operator", bob="monitor")
    long = tmp_path / "console_long.toml"
    long.write_text(LONG)
    service.scenarios = (*service.scenarios, str(long))  # offered, by its path, beside the shipped ones
    quiet = msgspec.structs.replace(
        service.bench.outputs, can_log=False, recording=False, plots=False, mcap=False
    )
    service.bench = msgspec.structs.replace(service.bench, outputs=quiet)  # the run's summary is enough here
    audit: list[str] = []
    browser = chromium(insecure_certs=True)
    try:
        server, _ = console("operator", tls=tls, accounts=people, audit=audit.append)
        assert server.url.startswith("https://")
        browser.get(server.url)

        def log_in(name: str, password: str) -> None:
            page_wait(browser, "return !document.getElementById('login').hidden", what="the login form")
            browser.find_element(By.ID, "login-name").clear()
            browser.find_element(By.ID, "login-name").send_keys(name)
            browser.find_element(By.ID, "login-password").send_keys(password)
            browser.find_element(By.ID, "login-submit").click()

        assert not browser.find_element(By.ID, "main").is_displayed(), "nothing but the form before a login"
        log_in("bob", "not-his-password")
        said = page_wait(browser, "return document.getElementById('login-message').textContent")
        assert said == "wrong name or password (HTTP 401)"
        log_in("bob", "bob-password")
        page_wait(browser, "return document.getElementById('role').textContent == 'monitor'")
        assert browser.find_element(By.ID, "person").text == "bob,"
        shown = [
            b.get_attribute("id") for b in browser.find_elements(By.TAG_NAME, "button") if b.is_displayed()
        ]
        assert shown == ["logout"], f"a monitor sees no action: {shown}"
        browser.find_element(By.ID, "logout").click()

        log_in("alice", "alice-password")
        page_wait(browser, "return document.getElementById('role').textContent == 'operator'")
        page_wait(
            browser,
            "return [...document.getElementById('scenario').options].some(o => o.value == "
            f"{json.dumps(str(long))})",
            what="the long scenario offered",
        )
        Select(browser.find_element(By.ID, "scenario")).select_by_value(str(long))
        browser.find_element(By.ID, "start").click()
        page_wait(
            browser, "return document.getElementById('run-age').textContent == 'live'", what="the run live"
        )
        browser.find_element(By.ID, "estop").click()
        message = page_message(browser, "latched by", what="the supervisor's confirmation")
        assert "latched by console operator alice" in message, message
        browser.find_element(By.ID, "stop").click()
        assert service.wait_idle(60)
    finally:
        browser.quit()
        shutil.rmtree(browser.profile_dir, ignore_errors=True)
    said = "\n".join(audit)
    for line in (
        "bob (?) from 127.0.0.1: login -> 401",
        "bob (monitor) from 127.0.0.1: login -> 200",
        "bob (monitor) from 127.0.0.1: logout -> 200",
        "alice (operator) from 127.0.0.1: start -> 200",
        "alice (operator) from 127.0.0.1: estop -> 200 supervisor",
        "alice (operator) from 127.0.0.1: stop -> 200",
    ):
        assert line in said, f"{line!r} not in the audit log:\n{said}"


TILTED = """
name = "console_tilted"
rider = "ref_60kg_180"
duration = 600.0  # lockstep: ended by the test
initial_tilt_deg = [5.0, -4.0]
"""
POSE_DRAWN = """(() => {
const el = (id) => document.getElementById(id), p = window.pureConsole.drawnPose;
const at = (id, name) => parseFloat(el(id).getAttribute(name));
const deg = (dx, dy) => Math.atan2(dx, dy) * 180 / Math.PI;
const lean = (line) => deg(at(line, 'x2') - at(line, 'x1'), at(line, 'y1') - at(line, 'y2'));
return {pose: p, side: lean('pose-side-chassis'), rear: lean('pose-rear-chassis'),
  side_torso: lean('pose-side-torso'), rear_torso: lean('pose-rear-torso'),
  ball: [at('pose-top-ball', 'cx'), at('pose-top-ball', 'cy')],
  heading: deg(at('pose-heading', 'y1') - at('pose-heading', 'y2'),
    at('pose-heading', 'x2') - at('pose-heading', 'x1')),
  shown: ['p-tilt-pitch', 'p-tilt-roll', 'p-heading', 'p-x', 'p-y'].map((id) => el(id).textContent),
  live: (window.pureConsole.lastLive || {}).pose, panel: el('pose-panel').className,
  age: el('pose-age').textContent};
})()"""
"""What the page drew of the pose, and what it says of it."""


def _drawn_as_sampled(drawn: dict) -> None:
    """The page's drawing says what the pose it drew says: each view's angle, the ball, the heading."""
    pose = drawn["pose"]
    (pitch, roll), (lean_pitch, lean_roll) = pose["tilt_deg"], pose["lean_deg"]
    assert drawn["side"] == pytest.approx(pitch, abs=0.05) and drawn["rear"] == pytest.approx(roll, abs=0.05)
    assert drawn["side_torso"] == pytest.approx(pitch + lean_pitch, abs=0.05), drawn
    assert drawn["rear_torso"] == pytest.approx(roll + lean_roll, abs=0.05), drawn
    x, y = pose["position"]
    assert drawn["ball"] == pytest.approx([x, -y], abs=1e-3), "from above: y up"
    assert (drawn["heading"] - pose["heading_deg"] + 180) % 360 - 180 == pytest.approx(0, abs=0.05)


def test_the_page_draws_the_pose_and_greys_it_when_the_service_goes(rig, tmp_path):
    """A run released tilted forward and to the left: the page draws it so (side view leaning forward, the
    view from behind to the left), its numbers and drawing say what the live pose says, the path grows; the
    service stops answering: the last pose stays, greyed, labelled stale with its age."""
    service, console = rig
    tilted = tmp_path / "console_tilted.toml"
    tilted.write_text(TILTED)
    service.scenarios = (*service.scenarios, str(tilted))
    quiet = msgspec.structs.replace(
        service.bench.outputs, can_log=False, recording=False, plots=False, mcap=False
    )
    service.bench = msgspec.structs.replace(service.bench, outputs=quiet)
    browser = chromium()
    try:
        server, _ = console("operator")
        browser.get(server.url)
        page_wait(browser, "return document.getElementById('link').textContent == 'service idle'")
        idle = browser.execute_script("return " + POSE_DRAWN)
        assert idle["age"] == "no run" and "none" in idle["panel"], idle
        status, reply = request(server.url + "api/start", {"scenario": str(tilted)})
        assert status == 200, reply
        # The first pose the page draws is the release: forward in the side view, left from behind.
        first = page_wait(browser, f"const d = {POSE_DRAWN}; return d.pose && d", what="a pose")
        assert first["side"] > 2.0 and first["rear"] < -1.5, f"forward, and to the left: {first}"
        _drawn_as_sampled(first)
        page_wait(browser, "return document.getElementById('pose-path').points.length > 3", what="a path")
        now = browser.execute_script("return " + POSE_DRAWN)
        _drawn_as_sampled(now)
        assert now["age"].startswith("live,") and "stale" not in now["panel"], now
        live = now["live"]
        numbers = [*live["tilt_deg"], live["heading_deg"]]
        assert now["shown"] == [f"{v:+.1f}" for v in numbers] + [f"{v:+.2f}" for v in live["position"]], now

        service.close()  # the run ends, and nothing answers any more
        service.close = lambda: None
        said = page_wait(
            browser,
            "const a = document.getElementById('pose-age').textContent; "
            "return a.includes('the service does not answer') && a",
            what="the pose stale",
        )
        assert re.fullmatch(r"stale: the service does not answer; [\d.]+ (s|min) old", said), said
        last = browser.execute_script("return " + POSE_DRAWN)
        assert "stale" in last["panel"] and "none" not in last["panel"], "the last pose, greyed"
        _drawn_as_sampled(last)
        opacity = browser.execute_script(
            "return getComputedStyle(document.getElementById('pose-side')).opacity"
        )
        assert float(opacity) < 1.0
        browser.save_screenshot(str(tmp_path / "pose.png"))
    finally:
        browser.quit()
        shutil.rmtree(browser.profile_dir, ignore_errors=True)


# ----------------------------------------------------------------------------------------- history
OLD_SCHEMA = """CREATE TABLE runs (id INTEGER PRIMARY KEY AUTOINCREMENT, folder TEXT NOT NULL,
    scenario TEXT NOT NULL, bench TEXT NOT NULL, controller TEXT NOT NULL, clock TEXT NOT NULL,
    verdict TEXT NOT NULL, first_cause TEXT, error TEXT, started REAL NOT NULL, ended REAL,
    files TEXT NOT NULL DEFAULT '', pid INTEGER NOT NULL)"""


def test_the_history_keeps_falls_faults_operator_actions_and_iso_times(tmp_path):
    import sqlite3

    from hil.history import History

    old = sqlite3.connect(tmp_path / "history.sqlite")
    old.execute(OLD_SCHEMA)
    old.execute(
        "INSERT INTO runs (folder, scenario, bench, controller, clock, verdict, started, ended, pid) "
        "VALUES ('old', 'balance', 'embedded', 'embedded reference hacs', 'lockstep', 'PASSED', 0, 60, 1)"
    )
    old.commit()
    old.close()
    history = History(tmp_path)  # a file of an older version: it gains the columns, empty for its rows
    try:
        folder = tmp_path / "push-1"
        folder.mkdir()
        push = {"kind": "plant.push", "force": [600.0, 0.0], "height": 0.4, "at": 1.0, "duration": 0.4}
        summary = {
            "fallen": True,
            "fall_cause": "tilt beyond 30 deg at t=2.348 s",
            "faults": [
                {"number": 0, "fault": push, "acted": [1.0, 1.4]},
                {"number": 1, "fault": {**push, "at": 9.0}, "acted": None},
            ],
            "operator_actions": [
                {"t": 3.2, "action": "estop", "source": "lab-operator-A", "supervisor_state": "STOPPING"}
            ],
        }
        (folder / "summary.json").write_text(json.dumps(summary))
        run = history.begin(folder, "push", "embedded", "embedded reference ihacs", "lockstep")
        history.end(run, "FAILED", "OPERATOR_ESTOP")
        bare = tmp_path / "bare-1"
        bare.mkdir()
        (bare / "summary.json").write_text(json.dumps({"fallen": False, "fall_cause": None, "faults": []}))
        history.end(history.begin(bare, "balance", "embedded", "x", "lockstep"), "PASSED")
        newest, pushed, older = history.runs()
        assert (pushed["fallen"], pushed["fall_cause"]) == (True, "tilt beyond 30 deg at t=2.348 s")
        first, never = pushed["faults"]
        assert first.startswith("plant.push") and first.endswith("acted 1-1.4 s"), first
        assert never.endswith("never acted"), never
        assert pushed["operator_actions"] == summary["operator_actions"]
        assert (newest["fallen"], newest["faults"], newest["operator_actions"]) == (False, [], None)
        assert (older["fallen"], older["faults"], older["operator_actions"]) == (None, None, None)
        iso = r"\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d[+-]\d\d:\d\d"
        assert all(re.fullmatch(iso, r[k]) for r in (newest, pushed, older) for k in ("started", "ended"))
        assert datetime.fromisoformat(older["ended"]).timestamp() == 60.0
    finally:
        history.close()
