// pure-hil console: the rig's screen. Live data arrives as Server-Sent Events from the console process
// (status once a second, live samples at ~20 Hz while a run goes, the supervisor's state, the e-stop latch);
// actions are JSON POSTs the console checks against the person's role and the rig it is pinned to before it
// asks the rig. Everything shown carries its age on the console's clock; what is old is shown stale. No build
// step, no outside resources.
"use strict";

const WINDOW = 20; // s of simulated time on the charts
const LIVE_STALE = 1.5; // s: the live stream comes every 50 ms while a run goes
const SAFETY_STALE = 2.0; // s: the supervisor speaks every 0.1 s simulated (hil/console/latch.py SILENT)
const STATUS_STALE = 3.5; // s: the console asks the status every second, each question waits up to 2 s
const PATH_STEP = 0.02; // m between the top view's path points, doubled each time the path is thinned
const PATH_MAX = 1000; // path points kept: past it every other one goes, so a run of weeks holds as many
const CHASSIS = 0.51, TORSO = 0.6; // m the pose views draw: ball centre to the hips, hips to the head
const SHADES = { // the supervisor's states as plots.png shades them
  LIMITING: "rgba(255, 215, 0, 0.35)", STOPPING: "rgba(255, 165, 0, 0.35)",
  RECOVERY: "rgba(0, 191, 255, 0.30)", ESTOP: "rgba(255, 0, 0, 0.25)",
};
const $ = (id) => document.getElementById(id);
const state = {
  info: null, run: null, series: [], scenarios: "", supervisorEvents: false, lastSafety: null,
  samples: 0, lastLive: null, history: [], status: null, latch: null, skew: null, connected: false,
  source: null, path: [], pathStep: PATH_STEP, drawnPose: null,
};
window.pureConsole = state; // what a test (or a curious operator) can read from the browser

function text(id, value) { $(id).textContent = value === null || value === undefined ? "-" : value; }
function fixed(value, digits) { return value === null || value === undefined ? "-" : value.toFixed(digits); }
function signed(value, digits) {
  return value === null || value === undefined ? "-" : (value >= 0 ? "+" : "") + value.toFixed(digits);
}
function say(message, good) {
  const el = $("message");
  el.textContent = message;
  el.className = "message " + (good ? "good" : "bad");
}
function failed(reply) { return `${reply.error || "refused"} (HTTP ${reply.httpStatus})`; }

// ---------------------------------------------------------------------------------------- the clock
// Every datum is stamped with the console's clock when the console heard it; each status tells the page
// that clock's reading, so a page ages everything by it, also once nothing arrives any more.
function consoleNow() { return Date.now() / 1000 + (state.skew === null ? 0 : state.skew); }
function age(at) { return at === null || at === undefined ? null : Math.max(0, consoleNow() - at); }
function ageText(seconds) {
  if (seconds === null) return "-";
  if (seconds < 10) return `${seconds.toFixed(1)} s`;
  if (seconds < 120) return `${Math.round(seconds)} s`;
  return `${Math.round(seconds / 60)} min`;
}

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  let reply;
  let response;
  try {
    response = await fetch(path, init);
  } catch (e) {
    return { ok: false, error: `the console does not answer (${e.message})`, httpStatus: 0 };
  }
  try { reply = await response.json(); } catch (e) { reply = { ok: false, error: response.statusText }; }
  reply.httpStatus = response.status;
  if (response.status === 401 && reply.login) showLogin(state.info ? "your session ended: log in again" : "");
  return reply;
}

// ----------------------------------------------------------------------------------------------- start
async function boot() {
  const info = await api("/api/info");
  if (info.httpStatus === 401) return; // the login form is up
  if (!info.ok) { text("card", info.error); return; }
  state.info = info;
  $("login").hidden = true;
  $("main").hidden = false;
  text("role", info.role);
  text("person", info.person ? `${info.person},` : "");
  $("logout").hidden = !info.login;
  showCard();
  const can = new Set(info.actions);
  if (can.has("estop")) {
    $("estop").hidden = false;
  } else {
    $("estop-none").hidden = false;
    $("estop-none").textContent = `e-stop: the operator's (role ${info.role} may not)`;
  }
  $("run-actions").hidden = !can.has("start");
  for (const [id, action] of [["start", "start"], ["stop", "stop"], ["reset", "reset"], ["cut-power", "estop"]]) {
    $(id).hidden = !can.has(action);
  }
  $("fault-actions").hidden = !can.has("inject");
  if (can.size === 0) {
    $("no-actions").hidden = false;
    $("no-actions").textContent = `Role ${info.role} watches only: this console offers no actions.`;
  }
  const kinds = $("fault-kind");
  kinds.replaceChildren(...info.faults.map((fault) => {
    const option = document.createElement("option");
    option.value = fault.kind;
    option.textContent = fault.kind;
    return option;
  }));
  kinds.onchange = showFault;
  showFault();
  wire();
  connect();
  loadHistory();
  setInterval(render, 500); // ages grow also when nothing arrives
}

function showLogin(message) {
  $("main").hidden = true;
  $("login").hidden = false;
  text("login-message", message || "");
  $("login").onsubmit = async (event) => {
    event.preventDefault();
    const reply = await api("/api/login", { name: $("login-name").value, password: $("login-password").value });
    $("login-password").value = "";
    if (!reply.ok) { text("login-message", failed(reply)); return; }
    location.reload(); // a fresh page for the person logged in
  };
}

function showCard() {
  const pinned = state.info.card || (state.status && state.status.pinned);
  text("card", pinned
    ? `opened for ${pinned.runs} on bench ${pinned.bench}, pid ${pinned.pid}, id ${pinned.id}, at ${pinned.endpoint}`
    : `bench ${state.info.bench} (through its router): pinned to the first rig that answers`);
}

function showFault() {
  const fault = state.info.faults.find((f) => f.kind === $("fault-kind").value);
  if (!fault) return;
  $("fault-params").value = JSON.stringify(fault.params);
  $("fault-doc").textContent = fault.doc;
}

function wire() {
  $("estop").onclick = () => estop(false);
  $("cut-power").onclick = () => {
    if (confirm("Cut the drives' power at once, even in motion (category 0)?")) estop(true);
  };
  $("logout").onclick = async () => { await api("/api/logout", {}); location.reload(); };
  $("start").onclick = async () => {
    const reply = await api("/api/start", { scenario: $("scenario").value });
    say(reply.ok ? `started ${reply.scenario} (run ${reply.run})` : failed(reply), reply.ok);
  };
  $("stop").onclick = async () => {
    const reply = await api("/api/stop", {});
    say(reply.ok ? (reply.stopping ? "stopping the run" : "no run to stop") : failed(reply), reply.ok);
  };
  $("reset").onclick = async () => {
    const reply = await api("/api/reset", {});
    if (reply.ok && reply.cleared) say(reply.message, true);
    else if (reply.confirmed) say(`reset: supervisor ${reply.state.state} (${reply.state.reason})`, reply.ok);
    else say(failed(reply), false);
  };
  $("inject").onclick = async () => {
    let fault;
    try {
      fault = JSON.parse($("fault-params").value || "{}");
    } catch (e) {
      say(`parameters: not JSON (${e.message})`, false);
      return;
    }
    fault.kind = $("fault-kind").value;
    fault.at = Number($("fault-at").value || 0);
    if ($("fault-duration").value) fault.duration = Number($("fault-duration").value);
    const reply = await api("/api/inject", fault);
    say(reply.ok ? `injected ${reply.fault}` : failed(reply), reply.ok);
  };
  $("clear").onclick = async () => {
    const number = $("fault-number").value;
    const reply = await api("/api/clear", { number: number === "" ? null : Number(number) });
    say(reply.ok ? `cleared ${reply.cleared}` : failed(reply), reply.ok);
  };
}

async function estop(cutPower) {
  say("e-stop sent, waiting for the supervisor…", true);
  const reply = await api("/api/estop", { cut_power: cutPower });
  if (reply.confirmed) {
    const s = reply.state;
    say(`${reply.action} latched by ${s.estop_by}: supervisor ${s.state} (${s.reason})`, true);
  } else {
    say(failed(reply), false);
  }
}

// ------------------------------------------------------------------------------------------ live data
function connect() {
  const source = new EventSource("/api/events");
  state.source = source;
  source.onopen = () => { state.connected = true; render(); };
  source.onerror = () => {
    state.connected = false;
    render();
    if (source.readyState === EventSource.CLOSED) { // refused (a session that ended): ask why, then again
      setTimeout(async () => {
        const info = await api("/api/info");
        if (info.httpStatus !== 401) connect();
      }, 1000);
    }
  };
  source.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
  source.addEventListener("live", (e) => onLive(JSON.parse(e.data)));
  source.addEventListener("safety", (e) => onSafety(JSON.parse(e.data)));
  source.addEventListener("latch", (e) => { state.latch = JSON.parse(e.data); render(); });
  source.addEventListener("history", () => loadHistory());
}

function onStatus(status) {
  state.skew = status.now - Date.now() / 1000;
  status.received = status.now;
  state.status = status;
  if (!state.info.card && status.pinned) showCard();
  if (!status.reachable) { render(); return; }
  const bench = status.bench || {};
  const rows = [["bench", bench.name], ["", bench.description], ["CAN", bench.can], ["controller", bench.controller],
    // where it runs, and which plug judges the runs (a lab's own, or the reference); external: not named
    ["supervisor", [bench.supervisor, bench.supervisor_plug].filter(Boolean).join(" ")], ["zenoh", bench.zenoh],
    ["rider on board", bench.rider_on_board ? "yes: no faults" : "no"]];
  const table = $("bench-parts");
  table.replaceChildren(...rows.map(([k, v]) => {
    const tr = document.createElement("tr");
    const th = document.createElement("th"); th.textContent = k;
    const td = document.createElement("td"); td.textContent = v === undefined ? "-" : v;
    tr.append(th, td);
    return tr;
  }));
  const listed = (status.scenarios || []).join(",");
  if (listed !== state.scenarios) {
    state.scenarios = listed;
    const select = $("scenario");
    const keep = select.value;
    select.replaceChildren(...status.scenarios.map((name) => {
      const option = document.createElement("option");
      option.value = name; option.textContent = name;
      return option;
    }));
    if (keep) select.value = keep;
  }
  $("no-faults").hidden = !bench.rider_on_board;
  $("no-faults").textContent = `bench ${bench.name} has a rider on board: fault injection is refused`;
  const faults = (status.faults || []).filter((f) => f.active);
  $("faults").replaceChildren(...faults.map((f) => {
    const li = document.createElement("li");
    li.textContent = `#${f.number} ${f.fault}`;
    return li;
  }));
  render();
}

function onLive(s) {
  state.samples += 1;
  state.lastLive = s;
  if (s.run !== state.run) {
    state.run = s.run;
    state.series = [];
    state.supervisorEvents = false;
    $("events").replaceChildren();
    text("run-name", `${s.scenario} (run ${s.run})`);
    state.path = [];
    state.pathStep = PATH_STEP;
  }
  state.series.push(s);
  trackPath(s);
  const first = s.t - WINDOW;
  while (state.series.length && state.series[0].t < first) state.series.shift();
  if (s.events) {
    state.supervisorEvents = true;
    for (const e of s.events) logEvent(`t=${e.t.toFixed(3)} ${e.from} → ${e.to} (${e.cause})`);
  }
  $("faults").replaceChildren(...(s.faults || []).map((f) => {
    const li = document.createElement("li"); li.textContent = f; return li;
  }));
  render();
  requestDraw();
}

function onSafety(s) {
  const previous = state.lastSafety;
  state.lastSafety = s;
  // A supervisor outside the rig's process: its state stream is the event log.
  if (!state.supervisorEvents && previous && previous.state !== s.state && !s.foreign) {
    logEvent(`t=${s.since.toFixed(3)} ${previous.state} → ${s.state} (${s.reason})`);
  }
  render();
}

function logEvent(line) {
  const li = document.createElement("li");
  li.textContent = line;
  $("events").appendChild(li);
  $("events").scrollTop = $("events").scrollHeight;
}

// ------------------------------------------------------------------------------------ what is current
function statusFresh() {
  const st = state.status;
  return !!(state.connected && st && st.reachable && age(st.received) <= STATUS_STALE);
}

function liveStale(s) {
  // Why the live sample `s` is not the rig's present ('' when it is).
  if (!s) return "no run yet";
  if (s.foreign) return "a different rig's";
  const st = state.status;
  if (!state.connected) return "the console does not answer";
  if (!statusFresh()) return "the service does not answer";
  // Only a status heard after the sample says its run ended: one from before it may predate the run's start.
  if ((st.state !== "running" || st.run !== s.run) && st.received >= s.received) return `run ${s.run} ended`;
  if (age(s.received) > LIVE_STALE) return "not heard lately";
  return "";
}

function safetyStale(s) {
  if (!s) return "never heard";
  if (s.foreign) return "a different rig's";
  if (!state.connected) return "the console does not answer";
  if (age(s.received) > SAFETY_STALE) return "the supervisor is silent";
  return "";
}

function field(name, value, at, why, bad) {
  const td = $("h-" + name);
  td.textContent = value === null || value === undefined ? "-" : value;
  td.classList.toggle("stale", !!why);
  td.classList.toggle("bad", !!bad);
  const a = age(at);
  const cell = $("a-" + name);
  cell.textContent = a === null ? "" : why ? `stale, ${ageText(a)} old` : `${ageText(a)} ago`;
  cell.title = why || "";
  cell.classList.toggle("stale", !!why);
}

// ------------------------------------------------------------------------------------------- render
function render() {
  if (!state.info) return;
  renderService();
  renderHealth();
  renderRun();
  renderPose();
  renderLatch();
  renderActions();
}

function renderService() {
  const st = state.status;
  const badge = $("link");
  const rigBanner = $("banner-rig"), serviceBanner = $("banner-service");
  let kind = "on", says;
  if (!state.connected) {
    kind = "bad"; says = "console unreachable";
  } else if (!st) {
    kind = "off"; says = "waiting for the service";
  } else if (!statusFresh()) {
    kind = "bad";
    says = `service not answering (${st.answered === null ? "never answered" : ageText(age(st.answered))})`;
  } else if (st.rig === "different") {
    kind = "bad"; says = "a different rig";
  } else {
    says = `service ${st.state}` + (st.state === "running" ? ` ${st.scenario}` : "");
  }
  badge.className = `badge ${kind}`;
  badge.textContent = says;
  serviceBanner.hidden = !st || statusFresh() || !state.connected;
  if (!serviceBanner.hidden) {
    const last = st.answered === null ? "it never answered" : `its last answer ${ageText(age(st.answered))} ago`;
    serviceBanner.textContent = `The service does not answer (${last}): every action is off, and the ` +
      "E-STOP answers that no rig answers (502). What is below is as it was last heard.";
  }
  rigBanner.hidden = !(st && st.reachable && st.rig === "different");
  if (!rigBanner.hidden) {
    const c = st.card || {}, p = st.pinned || {};
    rigBanner.textContent = `A DIFFERENT RIG answers on ${c.endpoint}: ${c.runs} on bench ${c.bench}, pid ` +
      `${c.pid}, id ${c.id}. This console was opened for ${p.runs} on bench ${p.bench}, pid ${p.pid}, id ` +
      `${p.id}: it refuses every action here (open a console for that rig). What is below is that rig's.`;
  }
  const service = !st ? "-" : !st.reachable ? "not answering"
    : st.state + (st.state === "running" ? ` ${st.scenario} (run ${st.run})` : "");
  field("service", service, st ? (st.reachable ? st.received : st.answered) : null,
    st && st.reachable && !statusFresh() ? "not asked lately" : "", st && !st.reachable);
}

function renderHealth() {
  const s = state.lastLive;
  const why = liveStale(s);
  const at = s ? s.received : null;
  const safetyWhy = state.lastSafety ? safetyStale(state.lastSafety) : "";
  const notes = [why && s ? `the run's data: ${why}` : "", safetyWhy ? `the supervisor's: ${safetyWhy}` : ""];
  text("health-note", notes.filter(Boolean).join("; ") ? `stale: ${notes.filter(Boolean).join("; ")}` : "");
  const live = (key, format) => (s ? format(s[key], s) : null);
  field("controller", live("controller", (v, x) => (x.heartbeat_hz === undefined ? "-" : `${v}, heartbeat ${x.heartbeat_hz} Hz`)), at, s && why);
  field("drives", live("permitted", (v, x) => `${v ? "permitted" : "not permitted"}, ${x.powered ? "powered" : "unpowered"}`
    + (x.resting ? ", at rest" : "") + (x.fall_cause ? `, FALLEN (${x.fall_cause})` : "")), at, s && why);
  field("contactor", live("contactor", (v) => (v ? "closed" : "open")), at, s && why);
  field("overruns", live("overruns", (v) => v), at, s && why);
  field("missing", live("missing_commands", (v) => v), at, s && why);
  field("factor", live("speed_factor", (v) => (v === null || v === undefined ? "-" : `${v.toFixed(2)}× real time`)), at, s && why);
  // The supervisor: its own state stream, else what the live stream last said of it.
  const safety = state.lastSafety;
  const name = safety ? safety.state : s ? s.supervisor : null;
  const sWhy = safety ? safetyStale(safety) : why;
  const sAt = safety ? safety.received : at;
  field("supervisor", name, sAt, name && sWhy);
  const el = $("h-supervisor");
  for (const c of [...el.classList]) if (c.startsWith("s-")) el.classList.remove(c);
  if (name && !sWhy) el.classList.add(`s-${name}`);
  field("cause", safety ? safety.reason : s ? s.cause : null, sAt, (safety || s) && sWhy);
}

function renderRun() {
  const s = state.lastLive;
  const why = liveStale(s);
  $("run-panel").classList.toggle("stale", !!(s && why));
  text("run-age", s ? (why ? `stale: ${why}; ${ageText(age(s.received))} old` : "live") : "");
  if (!s) return;
  text("r-t", fixed(s.t, 2));
  text("speed", signed(s.speed, 2));
  text("r-command", signed(s.command_speed, 2));
  text("r-sc-cap", s.sc_cap === null || s.sc_cap === undefined ? (s.sc_mode ? `none (${s.sc_mode})` : "-")
    : `±${s.sc_cap.toFixed(2)} m/s`);
  text("r-cap", s.cap === null || s.cap === undefined ? "-" : `±${s.cap.toFixed(2)} m/s`);
  text("r-tilt", signed(s.tilt_deg, 1));
  text("r-lean", signed(s.lean_deg, 1));
  const el = $("r-supervisor");
  el.textContent = s.supervisor || "-";
  el.className = s.supervisor ? `s-${s.supervisor}` : "";
}

function renderLatch() {
  const view = state.latch;
  const banner = $("estop-latched");
  const latched = view && view.latched;
  if (!latched) {
    banner.hidden = true;
    field("latch", view ? "none" : "-", view ? view.now : null, "");
    return;
  }
  const word = view.supervisor;
  const heard = word ? `supervisor ${word.state} (${word.reason}), heard ${ageText(age(word.at))} ago` : "";
  banner.hidden = false;
  if (latched.held_by === "supervisor") {
    banner.className = "banner latched";
    banner.textContent = `E-STOP LATCHED by ${latched.by}: ${heard}`;
    field("latch", `latched by ${latched.by} (the supervisor's)`, latched.since, "");
  } else {
    banner.className = "banner latched orphaned";
    const run = latched.run === null ? "" : ` in run ${latched.run}`;
    banner.textContent = `E-STOP by ${latched.by}${run} NEVER RESET: the supervisor that held it is gone ` +
      `(${latched.why}). This console holds it: Start is refused until Reset.`;
    field("latch", `by ${latched.by}${run}, held by this console: its supervisor is gone`, latched.since, "", true);
  }
}

function renderActions() {
  const st = state.status;
  const usable = statusFresh() && st.rig === "pinned";
  const off = $("actions-off");
  off.hidden = usable || !state.info.actions.length;
  off.textContent = !state.connected ? "Actions are off: the console does not answer."
    : !statusFresh() ? "Actions are off: the service does not answer."
      : "Actions are off: a different rig answers on this console's endpoint.";
  // The E-STOP and the category-0 cut are never off: a press always asks, and the console answers why not.
  for (const id of ["stop", "reset", "inject", "clear"]) $(id).disabled = !usable;
  const refusal = state.latch ? state.latch.start_refusal : "";
  $("start").disabled = !usable || !!refusal;
  text("start-refused", refusal ? `Start refused: ${refusal}` : "");
  const bench = (st && st.bench) || {};
  if (bench.rider_on_board) $("inject").disabled = true;
}

// --------------------------------------------------------------------------------------------- charts
let drawPending = false;
function requestDraw() {
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(() => {
    drawPending = false;
    const cap = (key, sign) => (s) => (s[key] === null || s[key] === undefined ? null : sign * s[key]);
    chart($("chart-speed"), "m/s", [
      ["speed", "#1565c0", [], (s) => s.speed], ["command", "#ef6c00", [], (s) => s.command_speed],
      ["SC cap", "#c62828", [6, 4], cap("sc_cap", 1)], [null, "#c62828", [6, 4], cap("sc_cap", -1)],
      ["supervisor cap", "#37474f", [2, 3], cap("cap", 1)], [null, "#37474f", [2, 3], cap("cap", -1)],
    ], 0.5);
    chart($("chart-angles"), "deg", [
      ["tilt", "#6a1b9a", [], (s) => s.tilt_deg], ["lean", "#2e7d32", [], (s) => s.lean_deg],
    ], 2);
    if (state.lastLive) drawPose(state.lastLive.pose);
  });
}

function niceStep(rough) {
  // 1, 2 or 5 times a power of ten: grid lines at round values.
  const power = Math.pow(10, Math.floor(Math.log10(rough)));
  const m = rough / power;
  return (m <= 1 ? 1 : m <= 2 ? 2 : m <= 5 ? 5 : 10) * power;
}

function chart(canvas, unit, lines, minSpan) {
  const ctx = canvas.getContext("2d");
  const W = canvas.width, H = canvas.height, L = 48, R = 8, T = 22, B = 20;
  ctx.clearRect(0, 0, W, H);
  const data = state.series;
  if (!data.length) return;
  const t1 = Math.max(data[data.length - 1].t, WINDOW), t0 = t1 - WINDOW;
  // The caps set the range only near the data (a 5 m/s cap never flattens a 0.3 m/s run).
  let lo = Infinity, hi = -Infinity;
  for (const s of data) for (const [, , , value] of lines.slice(0, 2)) {
    const v = value(s);
    if (v === null || v === undefined || !isFinite(v)) continue;
    lo = Math.min(lo, v); hi = Math.max(hi, v);
  }
  if (!isFinite(lo)) { lo = 0; hi = minSpan; }
  lo = Math.min(lo, 0); hi = Math.max(hi, 0);
  for (const s of data) for (const [, , , value] of lines.slice(2)) {
    const v = value(s);
    if (v !== null && isFinite(v) && Math.abs(v) < 2 * Math.max(Math.abs(lo), Math.abs(hi), minSpan)) {
      lo = Math.min(lo, v); hi = Math.max(hi, v);
    }
  }
  if (hi - lo < minSpan) { const mid = (hi + lo) / 2; lo = mid - minSpan / 2; hi = mid + minSpan / 2; }
  const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
  const x = (t) => L + ((t - t0) / (t1 - t0)) * (W - L - R);
  const y = (v) => T + (1 - (v - lo) / (hi - lo)) * (H - T - B);
  // The supervisor's states other than NORMAL shaded, one colour each, as plots.png does.
  let from = null, shaded = null;
  for (let i = 0; i <= data.length; i++) {
    const now = i < data.length ? data[i].supervisor : null;
    const shade = SHADES[now] ? now : null;
    if (shade !== shaded) {
      if (shaded !== null) {
        const a = x(Math.max(from, t0)), b = x(data[i - 1].t);
        ctx.fillStyle = SHADES[shaded];
        ctx.fillRect(a, T, Math.max(b - a, 1), H - T - B);
      }
      shaded = shade;
      from = i < data.length ? data[Math.max(i - 1, 0)].t : null;
    }
  }
  ctx.strokeStyle = "#d9dde3"; ctx.fillStyle = "#6b7280"; ctx.font = "11px sans-serif"; ctx.lineWidth = 1;
  const step = niceStep((hi - lo) / 4);
  for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) {
    ctx.beginPath(); ctx.moveTo(L, y(v)); ctx.lineTo(W - R, y(v)); ctx.stroke();
    ctx.fillText(v.toFixed(step < 1 ? 1 : 0).replace("-0.0", "0.0"), 4, y(v) + 4);
  }
  ctx.strokeStyle = "#9aa1ab";
  ctx.beginPath(); ctx.moveTo(L, y(0)); ctx.lineTo(W - R, y(0)); ctx.stroke(); // zero: the sign at a glance
  for (let t = Math.ceil(t0); t <= t1; t += 2) ctx.fillText(`${t}`, x(t) - 4, H - 5);
  ctx.fillText(unit, 4, 14);
  let legend = L;
  for (const [label, color, dash, value] of lines) {
    ctx.strokeStyle = color; ctx.lineWidth = dash.length ? 1.5 : 2; ctx.setLineDash(dash);
    ctx.beginPath();
    let pen = false;
    for (const s of data) {
      const v = value(s);
      if (v === null || v === undefined || !isFinite(v) || s.t < t0 || v < lo || v > hi) { pen = false; continue; }
      if (pen) ctx.lineTo(x(s.t), y(v)); else ctx.moveTo(x(s.t), y(v));
      pen = true;
    }
    ctx.stroke();
    ctx.setLineDash([]);
    if (label) { ctx.fillStyle = color; ctx.fillText(label, legend, 14); legend += ctx.measureText(label).width + 16; }
  }
}

// ----------------------------------------------------------------------------------------------- pose
// The live sample's pose (hil/live.py pose()): chassis tilt and torso lean (pitch, roll; the lean relative to
// the chassis, the torso drawn at tilt + lean), heading, the ball on the floor. Side view from the robot's
// right (forward to the right), the other from behind (the rider's right to the right): in both a positive
// angle leans the top to the right, as the signs go (pitch + forward, roll + right).
function trackPath(s) {
  if (!s.pose) return;
  const [x, y] = s.pose.position;
  const path = state.path;
  const last = path[path.length - 1];
  if (last && Math.hypot(x - last[0], y - last[1]) < state.pathStep) return;
  path.push([x, y]);
  if (path.length > PATH_MAX) { // thinned, never cut: the whole path stays, at half the detail
    state.path = path.filter((_, i) => i % 2 === 0 || i === path.length - 1);
    state.pathStep *= 2;
  }
}

function setAttrs(id, attrs) {
  const el = $(id);
  for (const [name, value] of Object.entries(attrs)) el.setAttribute(name, typeof value === "number" ? value.toFixed(4) : value);
}

function stick(view, chassisDeg, torsoDeg) {
  const c = (chassisDeg * Math.PI) / 180, t = (torsoDeg * Math.PI) / 180;
  const x = CHASSIS * Math.sin(c), y = -CHASSIS * Math.cos(c);
  setAttrs(`${view}-chassis`, { x2: x, y2: y });
  setAttrs(`${view}-torso`, { x1: x, y1: y, x2: x + TORSO * Math.sin(t), y2: y - TORSO * Math.cos(t) });
  $(`${view}-angle`).textContent = `${signed(chassisDeg, 1)}°`;
}

function drawPose(pose) {
  if (!pose) return;
  state.drawnPose = pose;
  const [pitch, roll] = pose.tilt_deg, [leanPitch, leanRoll] = pose.lean_deg;
  stick("pose-side", pitch, pitch + leanPitch);
  stick("pose-rear", roll, roll + leanRoll);
  // From above: world x to the right, y up (the SVG's y down, so -y); the view holds the path and the robot,
  // snapped to its grid so it moves only when the robot nears its edge.
  const [x, y] = pose.position;
  let x0 = x, x1 = x, y0 = y, y1 = y;
  for (const [px, py] of state.path) {
    x0 = Math.min(x0, px); x1 = Math.max(x1, px); y0 = Math.min(y0, py); y1 = Math.max(y1, py);
  }
  const want = Math.max(x1 - x0, y1 - y0) + 1.0;
  const step = niceStep(Math.max(want, 2) / 4);
  const left = Math.floor((x0 - 0.5) / step) * step, bottom = Math.floor((y0 - 0.5) / step) * step;
  const span = Math.max(Math.ceil((x1 + 0.5 - left) / step), Math.ceil((y1 + 0.5 - bottom) / step), 2) * step;
  const box = `${left} ${-(bottom + span)} ${span} ${span}`;
  const svg = $("pose-top");
  if (svg.getAttribute("viewBox") !== box) {
    svg.setAttribute("viewBox", box);
    const lines = [];
    for (let k = 0; k <= Math.round(span / step); k++) {
      const gx = left + k * step, gy = bottom + k * step;
      lines.push(`<line class="grid${Math.abs(gx) < 1e-9 ? " axis" : ""}" x1="${gx}" y1="${-bottom}" x2="${gx}" y2="${-(bottom + span)}"/>`);
      lines.push(`<line class="grid${Math.abs(gy) < 1e-9 ? " axis" : ""}" x1="${left}" y1="${-gy}" x2="${left + span}" y2="${-gy}"/>`);
    }
    $("pose-grid").innerHTML = lines.join("");
    text("pose-grid-step", step >= 1 ? `${step} m` : `${Math.round(step * 100)} cm`);
  }
  $("pose-path").setAttribute("points", [...state.path, [x, y]].map(([px, py]) => `${px},${-py}`).join(" "));
  const r = Math.max(0.1145, span * 0.015); // the ball to scale, never smaller than a dot
  setAttrs("pose-top-ball", { cx: x, cy: -y, r });
  const h = (pose.heading_deg * Math.PI) / 180, arrow = r + span * 0.12, head = span * 0.035;
  const tipX = x + arrow * Math.cos(h), tipY = -(y + arrow * Math.sin(h));
  setAttrs("pose-heading", { x1: x, y1: -y, x2: tipX, y2: tipY });
  const back = (side) => [tipX - head * Math.cos(h + side * 0.45), tipY + head * Math.sin(h + side * 0.45)];
  $("pose-heading-head").setAttribute("points", [[tipX, tipY], back(1), back(-1)].map((p) => p.join(",")).join(" "));
}

function renderPose() {
  const s = state.lastLive;
  const panel = $("pose-panel");
  const pose = s && s.pose;
  panel.classList.toggle("none", !pose);
  if (!pose) {
    panel.classList.remove("stale");
    text("pose-age", s ? "no pose in the live stream" : "no run");
    return;
  }
  const why = liveStale(s);
  const old = ageText(age(s.received));
  panel.classList.toggle("stale", !!why);
  text("pose-age", !why ? `live, ${old} ago`
    : why === `run ${s.run} ended` ? `no run (run ${s.run} ended): its last pose, ${old} old`
      : `stale: ${why}; ${old} old`);
  const [pitch, roll] = pose.tilt_deg, [leanPitch, leanRoll] = pose.lean_deg;
  text("p-tilt-pitch", signed(pitch, 1));
  text("p-tilt-roll", signed(roll, 1));
  text("p-lean-pitch", signed(leanPitch, 1));
  text("p-lean-roll", signed(leanRoll, 1));
  text("p-heading", signed(pose.heading_deg, 1));
  text("p-x", signed(pose.position[0], 2));
  text("p-y", signed(pose.position[1], 2));
}

// -------------------------------------------------------------------------------------------- history
function fall(run) {
  if (run.fallen === null || run.fallen === undefined) return "-";
  return run.fallen ? `FELL: ${run.fall_cause || "?"}` : "no";
}

function operatorActions(run) {
  const actions = run.operator_actions;
  if (!actions) return "-";
  if (!actions.length) return "none";
  return actions.map((a) => `${a.action} by ${a.source}` + (a.t === undefined ? "" : ` at ${Number(a.t).toFixed(2)} s`)
    + (a.supervisor_state ? ` (${a.supervisor_state})` : "")).join("; ");
}

async function loadHistory() {
  const reply = await api("/api/history?limit=50");
  if (!reply.ok) { text("history-total", reply.error); return; }
  state.history = reply.runs;
  // Each verdict counted apart (INCONCLUSIVE is neither a pass nor a fail), over the runs shown.
  const counts = {};
  for (const run of reply.runs) counts[run.verdict] = (counts[run.verdict] || 0) + 1;
  const shown = Object.entries(counts).map(([verdict, n]) => `${n} ${verdict}`).join(", ");
  text("history-total", `(${reply.total} runs${shown ? `; the last ${reply.runs.length}: ${shown}` : ""})`);
  const body = $("history").tBodies[0];
  body.replaceChildren(...reply.runs.map((run) => {
    const tr = document.createElement("tr");
    tr.dataset.run = run.id;
    const faults = run.faults === null || run.faults === undefined ? "-" : run.faults.length ? run.faults.join("; ") : "none";
    const cells = [run.id, run.scenario, run.bench, run.controller, run.clock, run.verdict, fall(run), faults,
      run.first_cause || "-", operatorActions(run), run.started || "-", run.ended || "-"];
    for (const value of cells) {
      const td = document.createElement("td"); td.textContent = value; tr.appendChild(td);
    }
    tr.children[5].className = `v-${run.verdict}`;
    if (run.fallen) tr.children[6].className = "bad";
    tr.children[10].className = tr.children[11].className = "when";
    const files = document.createElement("td");
    for (const name of run.files) {
      const a = document.createElement("a");
      a.href = `/runs/${run.id}/${encodeURIComponent(name)}`;
      a.textContent = name; a.target = "_blank"; a.rel = "noopener";
      files.appendChild(a);
    }
    tr.appendChild(files);
    return tr;
  }));
}

boot();
