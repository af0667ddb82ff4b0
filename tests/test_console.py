"""`pure-hil console`: the rig's screen in a browser.

In a real headless Chromium (Debian's chromium + chromium-driver, driven by Selenium; skipped, saying why,
where they are missing): `pure-hil serve` and `pure-hil console` as processes, speed_limiting started from
the page, the live speed seen rising, the e-stop pressed in the page and confirmed by the supervisor, the run
folder's summary saying OPERATOR_ESTOP and at rest, and the run still in the history after the service
restarts. Without a browser: the HTTP API's answers to good and bad requests, the role rules, no file
outside the service's output folder, pages that go away leave no thread behind; and on the secured bench
the router itself refuses a monitor's start and e-stop (the operator's, the positive control, get through).
"""

from __future__ import annotations

import http.client
import json
import os
import queue
import re
import shutil
import signal
import ssl
import subprocess
import sys
import tempfile
import threading
import time
import urllib.error
import urllib.request
from pathlib import Path
from types import SimpleNamespace

import pytest

from drivers.keys import Keys
from drivers.schemas import EstopCommand, SafetyState
from drivers.zenoh_link import ZenohLink, open_session
from hil.bench.bench import load_bench
from hil.bench.certs import init
from hil.console import rig_link
from hil.console.events import Broadcast
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


def request(url: str, body: dict | bytes | None = None, headers: dict | None = None) -> tuple[int, object]:
    """(status, JSON body or raw bytes) of a GET, or of a POST of `body`."""
    data = json.dumps(body).encode() if isinstance(body, dict) else body
    sent = {"Content-Type": "application/json"} if isinstance(body, dict) else {}
    req = urllib.request.Request(url, data=data, headers={**sent, **(headers or {})})
    try:
        with urllib.request.urlopen(req, timeout=30) as reply:
            status, raw, kind = reply.status, reply.read(), reply.headers.get_content_type()
    except urllib.error.HTTPError as exc:
        status, raw, kind = exc.code, exc.read(), exc.headers.get_content_type()
    return status, json.loads(raw) if kind == "application/json" else raw


# ------------------------------------------------------------------------------------------ a browser
def chromium():
    """A headless Chromium driven by Selenium through Debian's chromedriver, or a skip saying what is missing.
    Nothing it does leaves the machine: no background networking, updates, sync or first-run pings."""
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
        "--no-first-run",
        f"--user-data-dir={profile}",
        "--window-size=1400,1150",
    ):
        options.add_argument(flag)
    browser = webdriver.Chrome(service=Service(driver), options=options)
    browser.profile_dir = profile
    return browser


def page_wait(browser, script: str, timeout: float = 30.0, what: str = ""):
    """Wait until `script` (returning a value) is truthy in the page; its value."""
    value = wait_for(lambda: browser.execute_script(script), timeout, step=0.05)
    assert value, f"the page never showed {what or script} within {timeout} s"
    return value


def test_the_page_starts_a_run_sees_it_live_estops_it_and_keeps_it_in_the_history(tmp_path):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    browser = chromium()
    env, runs = _env(tmp_path), tmp_path / "runs"
    hub = f"tcp/127.0.0.1:{free_port()}"
    # Lockstep, as the scenario says: a real-time run's embedded controller misses its deadlines on a busy
    # machine and the supervisor stops the robot before the page does. The page reacts within a fraction of a
    # second of wall time, a few tenths of simulated time at this rig's speed, and the e-stop then lands
    # early in the scenario's 7 s of leaning: the robot is stopped and at rest long before its 12 s end.
    serve_args = ["serve", "--hub", hub, "--out", str(runs)]
    serve = Proc(serve_args, env)
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
        Select(browser.find_element(By.ID, "scenario")).select_by_value("speed_limiting")
        browser.find_element(By.ID, "start").click()
        page_wait(
            browser,
            "return parseFloat(document.getElementById('speed').textContent) > 0.15",
            what="the live speed rising past 0.15 m/s",
        )
        speeds = browser.execute_script("return window.pureConsole.series.map(s => s.speed)")
        assert min(speeds) < 0.05 and max(speeds) > 0.15, f"the live stream showed it rise: {speeds}"

        browser.find_element(By.ID, "estop").click()
        message = page_wait(
            browser,
            "const m = document.getElementById('message').textContent; return m.includes('latched by') && m",
            what="the supervisor's confirmation",
        )
        assert "OPERATOR_ESTOP" in message and "console operator" in message, message
        assert browser.find_element(By.ID, "estop-latched").is_displayed()
        verdict = page_wait(
            browser,
            "const r = document.querySelector('#history tr[data-run=\"1\"]'); "
            "return r && r.children[5].textContent != 'RUNNING' && r.children[5].textContent",
            timeout=60,
            what="the run's end in the history",
        )
        assert verdict == "ESTOPPED"
        browser.save_screenshot(str(tmp_path / "console.png"))
        assert (tmp_path / "console.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

        (folder,) = [p for p in runs.iterdir() if p.is_dir()]
        summary = json.loads((folder / "summary.json").read_text())
        steps = [(e["to_state"], e["cause"]) for e in summary["safety"]["events"]]
        assert ("STOPPING", "OPERATOR_ESTOP") in steps, steps
        assert summary["safety"]["ended_resting"] and summary["fallen"] is False
        assert summary["verdict"] == "ESTOPPED"

        # The service restarts (same hub); the console stays, and the run is still in the history.
        assert serve.stop() == 0
        serve = Proc(serve_args, env)
        serve.wait_line(r"pure-hil serve: bench embedded, hub")
        browser.refresh()
        row = page_wait(
            browser,
            "const r = document.querySelector('#history tr[data-run=\"1\"]'); "
            "return r && [...r.children].map(c => c.textContent)",
            what="run 1 after the restart",
        )
        assert row[1:3] == ["speed_limiting", "embedded"] and row[5:7] == ["ESTOPPED", "OPERATOR_ESTOP"], row
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

        # A monitor's console on the same rig: the same screen, no button at all.
        watcher = Proc(["console", "--identity", "monitor"], env)
        try:
            browser.get(watcher.wait_line(r"console: (http://127\.0\.0\.1:\d+/)").group(1))
            page_wait(browser, "return document.getElementById('role').textContent == 'monitor'")
            page_wait(
                browser, "return document.querySelector('#history tr[data-run=\"1\"]')", what="the history"
            )
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

    def console(role: str) -> tuple[Console, RigLink]:
        session = open_session(role="member", hub_endpoint=endpoint)
        link = RigLink(session, KEYS, role, f"test {role}", Broadcast())
        server = Console(link, {"card": None, "bench": "embedded", "faults": fault_catalog()}).start()
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
    assert request(api + "estop", {})[0] == 409, "no run: no supervisor listens (pure-hil estop says so too)"

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


class _StatusChangingLink(RigLink):
    """A RigLink without zenoh whose status reads as the given values in turn: the poller thread's write
    landing between two reads."""

    def __init__(self, *statuses):
        self._statuses = iter(statuses)
        self.keys = KEYS

    @property
    def status(self):
        return next(self._statuses)


def test_a_fault_is_refused_on_a_rider_bench_also_when_the_status_goes_meanwhile():
    link = _StatusChangingLink({"bench": {"name": "lab", "rider_on_board": True}}, None)
    with pytest.raises(rig_link.Refused, match="bench lab says a person is on the robot") as refused:
        link.inject({"kind": "zenoh.wrench_dropout"})
    assert refused.value.status == 409


def test_a_file_answer_without_its_size_is_a_bad_gateway():
    link = _StatusChangingLink()
    answer = SimpleNamespace(ok=SimpleNamespace(attachment=None, payload=None), err=None)
    link.session = SimpleNamespace(get=lambda *args, **kwargs: [answer])
    with pytest.raises(rig_link.Refused, match="does not say the file's size") as refused:
        link.file(1, "summary.json")
    assert refused.value.status == 502


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
