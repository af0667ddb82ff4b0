// pure-hil console: the rig's screen. Live data arrives as Server-Sent Events from the console process
// (status once a second, live samples at ~20 Hz while a run goes, the supervisor's state); actions are JSON
// POSTs the console checks against its role before it asks the rig. No build step, no outside resources.
"use strict";

const WINDOW = 20; // s of simulated time on the charts
const $ = (id) => document.getElementById(id);
const state = {
  info: null, run: null, series: [], scenarios: "", supervisorEvents: false, lastSafety: null,
  samples: 0, lastLive: null, history: [],
};
window.pureConsole = state; // what a test (or a curious operator) can read from the browser

function text(id, value) { $(id).textContent = value === null || value === undefined ? "-" : value; }
function fixed(value, digits) { return value === null || value === undefined ? "-" : value.toFixed(digits); }
function say(message, good) {
  const el = $("message");
  el.textContent = message;
  el.className = "message " + (good ? "good" : "bad");
}
function when(stamp) { return stamp ? new Date(stamp * 1000).toLocaleString() : "-"; }

async function api(path, body) {
  const init = body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body),
  };
  const response = await fetch(path, init);
  let reply;
  try { reply = await response.json(); } catch (e) { reply = { ok: false, error: response.statusText }; }
  reply.httpStatus = response.status;
  return reply;
}

// ----------------------------------------------------------------------------------------------- start
async function start() {
  const info = await api("/api/info");
  state.info = info;
  text("role", info.role);
  const card = info.card;
  text("card", card ? `${card.runs} on bench ${card.bench}, pid ${card.pid}, at ${card.endpoint}`
    : `bench ${info.bench} (through its router)`);
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
  for (const fault of info.faults) {
    const option = document.createElement("option");
    option.value = fault.kind;
    option.textContent = fault.kind;
    kinds.appendChild(option);
  }
  kinds.onchange = showFault;
  showFault();
  wire();
  connect();
  loadHistory();
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
  $("start").onclick = async () => {
    const reply = await api("/api/start", { scenario: $("scenario").value });
    say(reply.ok ? `started ${reply.scenario} (run ${reply.run})` : reply.error, reply.ok);
  };
  $("stop").onclick = async () => {
    const reply = await api("/api/stop", {});
    say(reply.ok ? (reply.stopping ? "stopping the run" : "no run to stop") : reply.error, reply.ok);
  };
  $("reset").onclick = async () => {
    const reply = await api("/api/reset", {});
    say(reply.confirmed ? `reset: supervisor ${reply.state.state} (${reply.state.reason})` : reply.error, reply.ok);
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
    say(reply.ok ? `injected ${reply.fault}` : reply.error, reply.ok);
  };
  $("clear").onclick = async () => {
    const number = $("fault-number").value;
    const reply = await api("/api/clear", { number: number === "" ? null : Number(number) });
    say(reply.ok ? `cleared ${reply.cleared}` : reply.error, reply.ok);
  };
}

async function estop(cutPower) {
  say("e-stop sent, waiting for the supervisor…", true);
  const reply = await api("/api/estop", { cut_power: cutPower });
  if (reply.confirmed) {
    const s = reply.state;
    say(`${reply.action} latched by ${s.estop_by}: supervisor ${s.state} (${s.reason})`, true);
  } else {
    say(reply.error || "e-stop not confirmed", false);
  }
}

// ------------------------------------------------------------------------------------------ live data
function connect() {
  const source = new EventSource("/api/events");
  source.onopen = () => { $("link").className = "badge on"; $("link").textContent = "live"; };
  source.onerror = () => { $("link").className = "badge off"; $("link").textContent = "reconnecting…"; };
  source.addEventListener("status", (e) => onStatus(JSON.parse(e.data)));
  source.addEventListener("live", (e) => onLive(JSON.parse(e.data)));
  source.addEventListener("safety", (e) => onSafety(JSON.parse(e.data)));
  source.addEventListener("history", () => loadHistory());
}

function onStatus(status) {
  if (!status.reachable) {
    text("h-service", "not answering");
    return;
  }
  text("h-service", status.state + (status.state === "running" ? ` ${status.scenario}` : ""));
  const bench = status.bench || {};
  const rows = [["bench", bench.name], ["", bench.description], ["CAN", bench.can], ["controller", bench.controller],
    ["supervisor", bench.supervisor], ["zenoh", bench.zenoh],
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
  $("inject").disabled = !!bench.rider_on_board;
  const faults = (status.faults || []).filter((f) => f.active);
  $("faults").replaceChildren(...faults.map((f) => {
    const li = document.createElement("li");
    li.textContent = `#${f.number} ${f.fault}`;
    return li;
  }));
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
  }
  state.series.push(s);
  const first = s.t - WINDOW;
  while (state.series.length && state.series[0].t < first) state.series.shift();
  text("r-t", fixed(s.t, 2));
  text("speed", fixed(s.speed, 2));
  text("r-command", fixed(s.command_speed, 2));
  text("r-cap", fixed(s.cap, 2));
  text("r-tilt", fixed(s.tilt_deg, 1));
  text("r-lean", fixed(s.lean_deg, 1));
  supervisorShown(s.supervisor);
  text("h-cause", s.cause);
  text("h-controller", s.heartbeat_hz === undefined ? "-" : `${s.controller}, heartbeat ${s.heartbeat_hz} Hz`);
  text("h-drives", `${s.permitted ? "permitted" : "not permitted"}, ${s.powered ? "powered" : "unpowered"}`
    + (s.resting ? ", at rest" : "") + (s.fall_cause ? `, FALLEN (${s.fall_cause})` : ""));
  text("h-contactor", s.contactor ? "closed" : "open");
  text("h-overruns", s.overruns);
  text("h-missing", s.missing_commands);
  text("h-factor", s.speed_factor === null ? "-" : `${s.speed_factor.toFixed(2)}× real time`);
  if (s.events) {
    state.supervisorEvents = true;
    for (const e of s.events) logEvent(`t=${e.t.toFixed(3)} ${e.from} → ${e.to} (${e.cause})`);
  }
  $("faults").replaceChildren(...(s.faults || []).map((f) => {
    const li = document.createElement("li"); li.textContent = f; return li;
  }));
  requestDraw();
}

function supervisorShown(name) {
  const el = $("r-supervisor");
  el.textContent = name || "-";
  el.className = name ? `s-${name}` : "";
  $("h-supervisor").textContent = name || "-";
  $("h-supervisor").className = el.className;
}

function onSafety(s) {
  const previous = state.lastSafety;
  state.lastSafety = s;
  supervisorShown(s.state);
  text("h-cause", s.reason);
  const latched = $("estop-latched");
  latched.hidden = !s.estop_by;
  latched.textContent = s.estop_by ? `E-STOP LATCHED by ${s.estop_by}: ${s.state}` : "";
  // A supervisor outside the rig's process: its state stream is the event log.
  if (!state.supervisorEvents && previous && previous.state !== s.state) {
    logEvent(`t=${s.since.toFixed(3)} ${previous.state} → ${s.state} (${s.reason})`);
  }
}

function logEvent(line) {
  const li = document.createElement("li");
  li.textContent = line;
  $("events").appendChild(li);
  $("events").scrollTop = $("events").scrollHeight;
}

// --------------------------------------------------------------------------------------------- charts
let drawPending = false;
function requestDraw() {
  if (drawPending) return;
  drawPending = true;
  requestAnimationFrame(() => {
    drawPending = false;
    chart($("chart-speed"), "m/s", [
      ["speed", "#1565c0", false], ["command_speed", "#ef6c00", false], ["cap", "#c62828", true],
    ], 0.5);
    chart($("chart-angles"), "deg", [["tilt_deg", "#6a1b9a", false], ["lean_deg", "#2e7d32", false]], 2);
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
  let lo = Infinity, hi = -Infinity;
  for (const s of data) for (const [key] of lines) {
    const v = s[key];
    if (v === null || v === undefined || !isFinite(v)) continue;
    lo = Math.min(lo, v); hi = Math.max(hi, v);
  }
  if (!isFinite(lo)) { lo = 0; hi = minSpan; }
  if (hi - lo < minSpan) { const mid = (hi + lo) / 2; lo = mid - minSpan / 2; hi = mid + minSpan / 2; }
  const pad = (hi - lo) * 0.08; lo -= pad; hi += pad;
  const x = (t) => L + ((t - t0) / (t1 - t0)) * (W - L - R);
  const y = (v) => T + (1 - (v - lo) / (hi - lo)) * (H - T - B);
  // The supervisor's interventions shaded, as plots.png does.
  ctx.fillStyle = "rgba(198, 40, 40, 0.10)";
  let from = null;
  for (let i = 1; i <= data.length; i++) {
    const acting = i < data.length && data[i].supervisor && data[i].supervisor !== "NORMAL";
    if (acting && from === null) from = data[i - 1].t;
    if (!acting && from !== null) {
      ctx.fillRect(x(Math.max(from, t0)), T, x(data[i - 1].t) - x(Math.max(from, t0)), H - T - B);
      from = null;
    }
  }
  ctx.strokeStyle = "#d9dde3"; ctx.fillStyle = "#6b7280"; ctx.font = "11px sans-serif"; ctx.lineWidth = 1;
  const step = niceStep((hi - lo) / 4);
  for (let v = Math.ceil(lo / step) * step; v <= hi; v += step) {
    ctx.beginPath(); ctx.moveTo(L, y(v)); ctx.lineTo(W - R, y(v)); ctx.stroke();
    ctx.fillText(v.toFixed(step < 1 ? 1 : 0).replace("-0.0", "0.0"), 4, y(v) + 4);
  }
  for (let t = Math.ceil(t0); t <= t1; t += 2) ctx.fillText(`${t}`, x(t) - 4, H - 5);
  ctx.fillText(unit, 4, 14);
  let legend = L;
  for (const [key, color, dashed] of lines) {
    ctx.strokeStyle = color; ctx.lineWidth = 2; ctx.setLineDash(dashed ? [6, 4] : []);
    ctx.beginPath();
    let pen = false;
    for (const s of data) {
      const v = s[key];
      if (v === null || v === undefined || s.t < t0) { pen = false; continue; }
      if (pen) ctx.lineTo(x(s.t), y(v)); else ctx.moveTo(x(s.t), y(v));
      pen = true;
    }
    ctx.stroke();
    ctx.setLineDash([]);
    ctx.fillStyle = color; ctx.fillText(key, legend, 14); legend += ctx.measureText(key).width + 16;
  }
}

// -------------------------------------------------------------------------------------------- history
async function loadHistory() {
  const reply = await api("/api/history?limit=50");
  if (!reply.ok) { text("history-total", reply.error); return; }
  state.history = reply.runs;
  text("history-total", `(${reply.total} runs)`);
  const body = $("history").tBodies[0];
  body.replaceChildren(...reply.runs.map((run) => {
    const tr = document.createElement("tr");
    tr.dataset.run = run.id;
    const cells = [run.id, run.scenario, run.bench, run.controller, run.clock, run.verdict, run.first_cause || "-",
      when(run.started), when(run.ended)];
    for (const value of cells) {
      const td = document.createElement("td"); td.textContent = value; tr.appendChild(td);
    }
    tr.children[5].className = `v-${run.verdict}`;
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

start();
