// The ground-support page: live values from the server's event stream, commands as JSON POSTs
// with the session's token (from the address `sil gsu` printed).
"use strict";

const TOKEN = new URLSearchParams(location.search).get("token") || "";
const $ = (id) => document.getElementById(id);
const HISTORY_S = 60;
const CHART_HZ = 10;
let state = {};
let history = [];  // [t, speed %N, reference %N, EGT K]
let pending = false;
// what the page showed: the age of the newest sensor frame at each screen update (ms), the
// updates of the last second, the events and screen updates in all
const stats = { latencies: [], renders: [], updates: 0, drawn: 0 };
window.gsuStats = stats;

// -- requests --------------------------------------------------------------------------------
async function api(path, body) {
  const init = { headers: { "X-GSU-Token": TOKEN } };
  if (body !== undefined) {
    init.method = "POST";
    init.headers["Content-Type"] = "application/json";
    init.body = JSON.stringify(body);
  }
  const response = await fetch(path, init);
  const answer = await response.json().catch(() => ({ error: `HTTP ${response.status}` }));
  if (!response.ok) throw new Error(answer.error || `HTTP ${response.status}`);
  return answer;
}

function say(id, text, ok) {
  const el = $(id);
  el.textContent = text;
  el.className = "msg " + (ok ? "ok" : "refused");
}

async function command(msgId, path, body, done) {
  try {
    const answer = await api(path, body || {});
    say(msgId, done || "done", true);
    return answer;
  } catch (err) {
    say(msgId, "refused: " + err.message, false);
    return null;
  }
}

// -- pages -----------------------------------------------------------------------------------
function showPage() {
  const name = (location.hash || "#dashboard").slice(1);
  for (const section of document.querySelectorAll(".page")) {
    section.hidden = section.id !== "page-" + name;
  }
  for (const a of document.querySelectorAll("nav a")) {
    a.classList.toggle("active", a.dataset.page === name);
  }
  if (name === "params" && !$("params-body").children.length) loadParams();
  if (name === "log") { loadLogbook(); loadFaults(); }
  if (name === "record") loadRecordings();
}
window.addEventListener("hashchange", showPage);

// -- the live stream -------------------------------------------------------------------------
function fmt(value, digits) {
  return typeof value === "number" ? value.toFixed(digits) : (value ?? "-");
}

// an enumeration as the A2L names it (the server gives the name; a bare number by ``names``)
function named(value, names) {
  return typeof value === "string" ? value : (names[value] ?? "-");
}

function render() {
  pending = false;
  stats.drawn += 1;
  const s = state;
  const now = Date.now() / 1000;
  if (typeof s.frame_s === "number") {
    stats.latencies.push((now - s.frame_s) * 1000);
    if (stats.latencies.length > 600) stats.latencies.shift();
  }
  stats.renders.push(now);
  while (stats.renders.length && stats.renders[0] < now - 1) stats.renders.shift();
  $("speed").textContent = fmt(s.speed_pct, 1);
  $("speed-rpm").textContent = fmt(s.speed_rpm, 0);
  $("speed-ref").textContent = fmt(s.speed_ref_pct, 1);
  $("egt").textContent = fmt(s.egt_k, 0);
  const limit = s.x_egt_limit_k;
  $("egt").classList.toggle("hot", typeof limit === "number" && s.egt_k > limit);
  $("egt-limit").textContent = fmt(limit, 0);
  $("egt-start").textContent = fmt(s.x_start_egt_limit_k, 0);
  $("egt-target").textContent = fmt(s.x_egt_start_target, 0);
  $("pump").textContent = fmt(s.pump_v, 2);
  $("pump-duty").textContent = fmt(s.pump_duty_pct, 1);
  $("pump-enable").textContent = s.pump_enable ? "enabled" : "off";
  $("supply").textContent = fmt(s.supply_v, 2);
  $("pump-current").textContent = fmt(s.pump_current_a, 2);
  $("state").textContent = s.ecu_silent ? "silent" : (s.state ?? "-");
  $("step").textContent = s.step ?? "-";
  $("abort").textContent = s.abort_reason ?? "-";
  $("owner").textContent = s.owner ?? "-";
  $("health").textContent = fmt(s.pump_health_pct, 1);
  $("demand-source").textContent = named(s.x_demand_source, ["CAN", "BENCH", "NONE"]);
  $("faults").textContent = (s.faults && s.faults.length) ? s.faults.join(", ") : "none";
  $("bench-throttle").textContent = fmt(s.x_bench_throttle, 1);
  $("test-active").textContent = named(s.x_test_active, ["NONE", "GLOW", "STARTER", "PRIME"]);
  $("test-left").textContent = fmt(
    typeof s.x_test_time_left === "number" ? s.x_test_time_left / 1000 : undefined, 1);
  $("record-state").textContent = s.recording ? `recording: ${s.recorded_frames} frames` : "not recording";
  const x = s.xcp || {};
  $("link-bus").textContent = `bus: ${s.frames ?? 0} frames`;
  $("link-ecu").textContent = x.connected ? `ECU: ${x.ecu} · ${x.unlocked ? "unlocked" : "locked"}`
    : "ECU: no XCP session";
  $("unlock").disabled = !!x.unlocked;
  $("rate").textContent = stats.renders.length;
  const sorted = stats.latencies.slice(-100).sort((a, b) => a - b);
  $("latency").textContent = sorted.length ? fmt(sorted[Math.floor(sorted.length / 2)], 0) : "-";
  const banner = $("banner");
  banner.hidden = !(s.ecu_silent || s.x_error);
  banner.textContent = s.ecu_silent ? "No status frame from the ECU: is it running on this bus?"
    : (s.x_error || "");
  drawChart();
}

function onState(event) {
  state = JSON.parse(event.data);
  stats.updates += 1;
  const last = history.length ? history[history.length - 1][0] : 0;
  if (state.sent_s - last >= 1 / CHART_HZ) {
    history.push([state.sent_s, state.speed_pct, state.speed_ref_pct, state.egt_k]);
    while (history.length && history[0][0] < state.sent_s - HISTORY_S) history.shift();
  }
  if (!pending) { pending = true; requestAnimationFrame(render); }
}

function connect() {
  const source = new EventSource(`/api/stream?token=${encodeURIComponent(TOKEN)}`);
  source.onmessage = onState;
  source.onerror = () => { $("link-bus").textContent = "bus: page server unreachable"; };
}

// -- the chart -------------------------------------------------------------------------------
function drawChart() {
  const canvas = $("chart");
  const g = canvas.getContext("2d");
  const w = canvas.width, h = canvas.height, pad = 40;
  g.clearRect(0, 0, w, h);
  g.strokeStyle = "#d4d9df"; g.fillStyle = "#5d6670"; g.font = "12px sans-serif";
  for (let k = 0; k <= 4; k++) {
    const y = pad / 2 + (h - pad) * k / 4;
    g.beginPath(); g.moveTo(pad, y); g.lineTo(w - pad, y); g.stroke();
    g.fillText(String(120 - 30 * k), 4, y + 4);
    g.fillText(String(1200 - 300 * k), w - pad + 4, y + 4);
  }
  if (history.length < 2) return;
  const t1 = history[history.length - 1][0], t0 = t1 - HISTORY_S;
  const px = (t) => pad + (w - 2 * pad) * (t - t0) / HISTORY_S;
  const line = (k, top, color) => {
    g.strokeStyle = color; g.lineWidth = 2; g.beginPath();
    let started = false;
    for (const row of history) {
      if (typeof row[k] !== "number") { started = false; continue; }
      const y = pad / 2 + (h - pad) * (1 - Math.min(row[k], top) / top);
      if (started) g.lineTo(px(row[0]), y); else g.moveTo(px(row[0]), y);
      started = true;
    }
    g.stroke(); g.lineWidth = 1;
  };
  const css = getComputedStyle(document.documentElement);
  line(2, 120, css.getPropertyValue("--ref"));
  line(1, 120, css.getPropertyValue("--speed"));
  line(3, 1200, css.getPropertyValue("--egt"));
}

// -- start, throttle, stop, tests ------------------------------------------------------------
$("unlock").onclick = () => command("run-msg", "/api/unlock", {}, "unlocked");
$("start").onclick = () => $("confirm").showModal();
$("start-cancel").onclick = () => $("confirm").close();
$("start-confirm").onclick = async () => {
  $("confirm").close();
  await command("run-msg", "/api/start", { confirm: true }, "start asked: the ECU arms");
};
$("stop").onclick = () => command("run-msg", "/api/stop", {}, "stop asked");
$("throttle-range").oninput = () => { $("throttle").value = $("throttle-range").value; };
$("throttle-set").onclick = () => {
  const pct = Number($("throttle").value);
  return command("run-msg", "/api/throttle", { pct }, `throttle ${pct} %N`);
};
for (const button of document.querySelectorAll("button[data-test]")) {
  button.onclick = () => {
    const test = button.dataset.test;
    const level = test === "glow" ? 0 : Number($(`${test}-level`).value);
    const seconds = Number($(`${test}-s`).value);
    return command("test-msg", "/api/test", { test, level, seconds }, `${test} running`);
  };
}
$("test-end").onclick = () => command("test-msg", "/api/end-test", {}, "test ended");

// -- parameters ------------------------------------------------------------------------------
function shown(value) {
  return Array.isArray(value) ? value.map((v) => +v.toPrecision(6)).join(", ")
    : (typeof value === "number" ? String(+value.toPrecision(6)) : "-");
}

// the parameters read from the ECU into the table (``quiet``: the message line is left as it is)
async function loadParams(quiet) {
  if (!quiet) say("params-msg", "reading from the ECU ...", true);
  let rows;
  try { rows = await api("/api/params"); } catch (err) { say("params-msg", err.message, false); return; }
  const body = $("params-body");
  body.replaceChildren();
  for (const p of rows) {
    const tr = document.createElement("tr");
    tr.dataset.name = p.name;
    tr.innerHTML = `<td title=""></td><td data-testid="param-value-${p.name}"></td><td></td><td></td>
      <td><input data-testid="param-input-${p.name}"></td>
      <td><button data-testid="param-write-${p.name}">Write</button></td>`;
    const cells = tr.children;
    cells[0].textContent = p.name; cells[0].title = p.comment;
    cells[1].textContent = p.error ? p.error : shown(p.value);
    cells[2].textContent = p.unit;
    cells[3].textContent = `${p.lower} … ${p.upper}`;
    const msg = document.createElement("tr");
    msg.innerHTML = `<td colspan="6" data-testid="param-msg-${p.name}" class="refused"></td>`;
    msg.hidden = true;
    tr.querySelector("button").onclick = () => writeParam(p, tr, msg);
    body.append(tr, msg);
  }
  if (!quiet) say("params-msg", `${rows.length} parameters`, true);
}

async function writeParam(p, tr, msg) {
  const text = tr.querySelector("input").value.trim();
  const numbers = text.split(/[,\s]+/).filter(Boolean).map(Number);
  const value = p.kind === "CURVE" ? numbers : numbers[0];
  const cell = msg.firstElementChild;
  msg.hidden = false;
  try {
    const answer = await api("/api/params", { name: p.name, value });
    tr.children[1].textContent = shown(answer.value);
    cell.className = "ok"; cell.textContent = "written (store to flash to keep it)";
  } catch (err) {
    cell.className = "refused"; cell.textContent = "refused: " + err.message;
  }
}

$("params-reload").onclick = () => loadParams(false);
$("params-filter").oninput = () => {
  const f = $("params-filter").value.toLowerCase();
  for (const tr of $("params-body").querySelectorAll("tr[data-name]")) {
    tr.hidden = !tr.dataset.name.toLowerCase().includes(f);
  }
};
$("store").onclick = () => command("params-msg", "/api/store", {}, "stored to flash");
$("export").onclick = async (event) => {
  event.preventDefault();
  try {
    const file = await api("/api/export");
    const blob = new Blob([JSON.stringify(file, null, 1)], { type: "application/json" });
    const a = document.createElement("a");
    a.href = URL.createObjectURL(blob);
    a.download = `parameters-${file.saved.replace(/[:]/g, "")}.json`;
    a.click();
    say("params-msg", `exported ${Object.keys(file.parameters).length} parameters`, true);
  } catch (err) { say("params-msg", err.message, false); }
};
$("import").onchange = async () => {
  const file = $("import").files[0];
  if (!file) return;
  let document_;
  try { document_ = JSON.parse(await file.text()); } catch (err) {
    say("params-msg", `${file.name}: not JSON (${err.message})`, false); return;
  }
  const answer = await command("params-msg", "/api/import", document_);
  if (answer) {
    const refused = answer.refused.map((r) => r.reason).join("; ");
    say("params-msg", `${file.name}: ${answer.written.length} written` +
      (refused ? `; refused: ${refused}` : "") +
      (answer.unknown.length ? `; not in this ECU: ${answer.unknown.join(", ")}` : ""), !refused);
    loadParams(true);
  }
  $("import").value = "";
};

// -- logbook and faults ----------------------------------------------------------------------
async function loadLogbook() {
  try {
    const b = await api("/api/logbook");
    $("logbook-runs").textContent = b.log_runs ?? "-";
    const s = b.log_run_time_s;
    $("logbook-time").textContent = typeof s === "number"
      ? `${Math.floor(s / 3600)} h ${Math.floor(s / 60) % 60} min ${Math.round(s % 60)} s` : "-";
    $("logbook-starts").textContent = b.log_starts ?? "-";
    const aborts = Object.entries(b).filter(([k]) => k.startsWith("log_aborts_"));
    $("logbook-aborts").textContent = aborts.filter(([, v]) => v)
      .map(([k, v]) => `${k.slice(11)}: ${v}`).join(", ") || "none";
    $("logbook-egt").textContent = typeof b.log_last_max_egt === "number" ? `${b.log_last_max_egt.toFixed(1)} K` : "-";
    $("logbook-speed").textContent = typeof b.log_last_max_speed === "number" ? `${b.log_last_max_speed.toFixed(1)} %N` : "-";
    $("logbook-shutdown").textContent = b.log_last_shutdown ?? "-";
    say("logbook-msg", "", true);
  } catch (err) { say("logbook-msg", err.message, false); }
}
$("logbook-reload").onclick = loadLogbook;

async function loadFaults() {
  const rows = await api("/api/faults").catch(() => []);
  const body = $("fault-body");
  body.replaceChildren();
  for (const f of rows.slice().reverse()) {
    const tr = document.createElement("tr");
    const s = f.snapshot;
    for (const text of [new Date(f.wall_s * 1000).toLocaleTimeString(), f.bits.join(", "), s.state,
      fmt(s.speed_pct, 1), fmt(s.egt_k, 0), fmt(s.pump_v, 2)]) {
      const td = document.createElement("td"); td.textContent = text ?? "-"; tr.append(td);
    }
    body.append(tr);
  }
}

// -- recording -------------------------------------------------------------------------------
async function loadRecordings() {
  const list = await api("/api/recordings").catch(() => []);
  $("recordings").replaceChildren(...list.map((r) => {
    const li = document.createElement("li");
    li.textContent = `${r.path}: ${r.frames} frames, ${(r.bytes / 1024).toFixed(0)} KiB`;
    return li;
  }));
}
$("record-start").onclick = () => command("record-msg", "/api/record/start", {}, "recording");
$("record-stop").onclick = async () => {
  const done = await command("record-msg", "/api/record/stop", {});
  if (done) { say("record-msg", `written: ${done.path}`, true); loadRecordings(); }
};

// -- start -----------------------------------------------------------------------------------
api("/api/chart").then((rows) => {
  history = rows.map((r) => [r[0], r[1], r[2], r[3]]).concat(history);
}).catch(() => {});
showPage();
connect();
