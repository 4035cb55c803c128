// The ncgate console: one server-sent-event stream (/api/stream) feeds everything; writes and
// commands go to /api/write and /api/command. No build step, no library. Text from the server
// is always set with textContent (never as HTML).
"use strict";
const $ = (s) => document.querySelector(s);
const el = (tag, cls, text) => {
  const e = document.createElement(tag);
  if (cls) e.className = cls;
  if (text !== undefined) e.textContent = text;
  return e;
};
const SVG = "http://www.w3.org/2000/svg";
const KEEP = 3000;          // events the page keeps (the timeline's)
const LOG_ROWS = 300;       // rows the event log shows, newest first
const WINDOW_S = 30;        // the timeline shows the last WINDOW_S seconds of machine time
const TICK_MS = 250;        // the timeline is redrawn on this clock, never per message
let token = sessionStorage.getItem("ncgate-token") || "";
let session = null, lastSeq = -1, status = null, events = [], source = null;
let pending = {};           // the status parts received but not drawn yet
let timelineDirty = false, timelineAt = 0;
const kinds = new Set();

// ---- the stream -------------------------------------------------------------------------
function connect() {
  const url = "/api/stream" + (lastSeq >= 0 ? "?since=" + lastSeq : "");
  source = new EventSource(url);
  source.onopen = () => setConn(true);
  source.onerror = () => {
    setConn(false);
    if (source.readyState === EventSource.CLOSED) {  // refused (e.g. 503): try again later
      source = null;
      setTimeout(connect, 2000);
    }  // otherwise the browser reconnects by itself (retry: 1000)
  };
  // A status message holds what changed since the last one (the first one of a stream holds
  // everything, perhaps in several messages): merged here, and only those parts redrawn.
  source.addEventListener("status", (e) => {
    const s = JSON.parse(e.data);
    if (s.session !== undefined) {
      if (session !== null && s.session !== session) {
        // Another run (a restart, another config): start afresh, and read its events from
        // its first (the stream resumed at the old run's last id would skip them).
        resetSession();
        source.close();
        connect();
        return;
      }
      session = s.session;
    }
    if (status === null) status = {};
    if (s.t !== undefined) statusAt = performance.now();
    for (const [k, v] of Object.entries(s)) {
      if (k === "image") status.image = Object.assign(status.image || {}, v);
      else status[k] = v;
      pending[k] = true;
    }
    render();
  });
  source.addEventListener("events", (e) => {
    const batch = JSON.parse(e.data);
    const fresh = [];
    for (const ev of batch.events) if (addEvent(ev)) fresh.push(ev);
    if (events.length > KEEP) events.splice(0, events.length - KEEP);
    appendLog(fresh);
    timelineDirty = true;
  });
}
function setConn(up) {
  live = up;
  const c = $("#conn");
  c.textContent = up ? "live" : "reconnecting…";
  c.className = up ? "up" : "down";
  $("#offline").hidden = up;
  document.body.classList.toggle("offline", !up);
  controls();
}
// Buttons act only while the gateway answers (and the console is not read-only): a page
// whose server stopped must not look as if a click would do something.
function controls() {
  const off = !live || !status || !status.web || status.web.read_only;
  for (const b of document.querySelectorAll("nav button, nav select, #lanes button")) {
    b.disabled = off;
  }
}
function resetSession() {  // another run: its lanes, programs, events start afresh
  events = [];
  lastSeq = -1;
  status = null;
  session = null;
  pending = {};
  kinds.clear();
  drawnSa = "";
  drawnSaBy = [];
  for (const box of ["#lanes", "#log tbody", "#sa", "#k", "#syvar", "#plc", "#fieldbus",
                     "#start-process", "#start-program"]) {
    $(box).replaceChildren();
  }
  for (const box of ["#filter-proc", "#filter-kind"]) $(box).replaceChildren($(box).options[0]);
  timelineDirty = true;
  loadPrograms();
}
function addEvent(ev) {
  if (ev.seq <= lastSeq) return false;
  lastSeq = ev.seq;
  events.push(ev);
  if (!kinds.has(ev.event)) {
    kinds.add(ev.event);
    const o = el("option", null, ev.event);
    o.value = ev.event;
    $("#filter-kind").append(o);
  }
  return true;
}

// ---- acting -------------------------------------------------------------------------------
async function post(path, body) {
  if (!live) { say("the gateway is not answering"); return false; }
  const headers = { "Content-Type": "application/json" };
  if (token) headers.Authorization = "Bearer " + token;
  const r = await fetch(path, { method: "POST", headers, body: JSON.stringify(body) });
  const answer = await r.json().catch(() => ({}));
  if (r.status === 401) {
    $("#token").hidden = false;
    $("#token").focus();
  }
  say(r.ok ? "" : (answer.error || r.statusText));
  return r.ok;
}
function say(text) { $("#message").textContent = text; }
for (const b of document.querySelectorAll("button[data-command]")) {
  b.addEventListener("click", () => post("/api/command", { command: b.dataset.command }));
}
$("#start-form").addEventListener("submit", (e) => {
  e.preventDefault();
  post("/api/command", { command: "start", program: $("#start-program").value,
                         process: Number($("#start-process").value) });
});
// The commissioning controls (issue 27): the cell's single block, run to sync, breakpoints,
// the feed override.
$("#single-block").addEventListener("change", () =>
  post("/api/command", { command: "single_block", on: $("#single-block").checked }));
$("#btn-sync").addEventListener("click", () => post("/api/command", { command: "run_to_sync" }));
$("#break-form").addEventListener("submit", (e) => {
  e.preventDefault();
  post("/api/command", { command: "break", at: $("#break-at").value });
});
$("#feed-override").addEventListener("change", () =>
  write("FEED_OVERRIDE", Number($("#feed-override").value)));
function renderControls() {
  const c = status.controls;
  if (!c) return;
  const box = $("#breakpoints");
  box.replaceChildren();
  for (const at of c.breakpoints) {  // each with its own clear button
    const b = el("button", "breakpoint", at + " \u00d7");
    b.title = "clear the breakpoint " + at;
    b.addEventListener("click", () => post("/api/command", { command: "break", at, on: false }));
    box.append(b);
  }
  const p1 = status.processes && status.processes[0];
  if (p1 && document.activeElement !== $("#feed-override")) {
    $("#feed-override").value = p1.feed_override;
  }
  if (p1) $("#single-block").checked = status.processes.every((p) => p.external || p.single_block);
}
$("#token").addEventListener("change", () => {
  token = $("#token").value;
  sessionStorage.setItem("ncgate-token", token);
});
function write(variable, value) { return post("/api/write", { var: variable, value }); }

// ---- rendering ----------------------------------------------------------------------------
function render() {
  if (!status.processes || !status.image || !status.web || !status.fieldbus) return;
  const parts = pending;
  pending = {};
  renderClock();
  $("#source").textContent = status.config;
  if (status.web.token && !token) $("#token").hidden = false;
  if (parts.processes) renderLanes();
  if (parts.processes || parts.controls) renderControls();
  if (parts.processes || parts.plc) renderAlarms();
  controls();
  if (parts.image) renderImage();
  if (parts.plc) renderPlc();
  if (parts.fieldbus) renderFieldbus();
  if (!parts.processes) return;
  const procs = $("#start-process");
  if (procs.options.length !== status.processes.length) {
    procs.replaceChildren();
    const filter = $("#filter-proc");
    for (const p of status.processes) {
      const o = el("option", null, "P" + p.number);
      o.value = p.number;
      procs.append(o);
      filter.append(o.cloneNode(true));
    }
  }
}
function renderLanes() {
  const box = $("#lanes");
  for (const p of status.processes) {
    let lane = document.getElementById("lane-" + p.number);
    if (!lane) {
      lane = el("div", "lane");
      lane.id = "lane-" + p.number;
      lane.append(el("span", "num", "P" + p.number), el("span", "state"));
      if (!p.external) {  // this process's own commands (issue 27): the command of one process
        const controls = el("span", "controls");
        for (const [command, label] of [["cycle_start", "Start"], ["feed_hold", "Hold"],
                                        ["step", "Step"], ["reset", "Reset"]]) {
          const b = el("button", "lane-" + command, label);
          b.title = label + " process " + p.number;
          b.addEventListener("click", () => post("/api/command", { command,
                                                                   process: p.number }));
          controls.append(b);
        }
        lane.append(controls);
      }
      lane.append(el("div", "detail"));
      box.append(lane);
    }
    const state = lane.querySelector(".state");
    state.textContent = p.state + (p.external ? " (external)" : "") + (p.held ? " held" : "");
    state.className = "state s-" + p.state;
    const detail = lane.querySelector(".detail");
    detail.replaceChildren();
    if (p.program) {
      detail.append(el("div", "block", p.program + ":" + p.line + "  " + p.block));
    }
    if (p.wait) {
      const w = p.wait;
      const wait = el("div", "wait", w.code + " " + w.reason + " ");
      const since = el("span", "since");  // the tick keeps it going
      since.dataset.since = w.since;
      wait.append(since);
      detail.append(wait);
      waitFor(since);
    }
    if (p.alarm) {
      const a = el("div", "alarm", p.alarm.code + ": " + p.alarm.message + " ");
      const reset = el("button", null, "Reset");
      reset.addEventListener("click", () => post("/api/command", { command: "reset" }));
      a.append(reset);
      detail.append(a);
    }
    detail.append(el("small", null, p.blocks + " blocks, " + p.snd_sent + " SND sent, " +
                     p.snd_received + " received"));
  }
}
// Every alarm pending, in the header, where it shows whatever part of the page is in view.
function renderAlarms() {
  const said = [];
  for (const p of status.processes) {
    if (p.alarm) {
      const w = p.alarm.where;
      said.push("P" + p.number + " " + p.alarm.code + (w ? " at " + w.prog + ":" + w.line +
                (w.n !== null && w.n !== undefined ? " N" + w.n : "") : ""));
    }
  }
  if (status.plc && status.plc.fault) said.push("PLC FAULT: " + status.plc.fault);
  $("#alarms").textContent = said.join("; ");
}
function cells(box, count, make) {
  if (box.children.length !== count) {
    box.replaceChildren();
    for (let i = 0; i < count; i++) box.append(make(i));
  }
  return box.children;
}
let drawnSa = "", drawnSaBy = [];
function renderImage() {
  const img = status.image;
  const sa = cells($("#sa"), img.sa.length, (i) => {
    const c = el("span", null, "");
    c.id = "sa-" + i;
    c.addEventListener("click", () => write("SA" + i, c.classList.contains("on") ? 0 : 1));
    return c;
  });
  if (sa.length !== drawnSaBy.length) { drawnSa = ""; drawnSaBy = new Array(sa.length); }
  for (let i = 0; i < img.sa.length; i++) {
    const who = img.writers.SA[i];
    if (img.sa[i] === drawnSa[i] && who === drawnSaBy[i]) continue;  // as drawn
    drawnSaBy[i] = who;
    const on = img.sa[i] === "1";
    const c = sa[i];
    c.classList.toggle("on", on);
    c.textContent = i % 8 === 0 ? String(i) : "";
    c.title = "SA" + i + " = " + (on ? 1 : 0) + (who ? " (last written by " + who + ")" : "");
    c.classList.toggle("ext", !!who && who !== "plc");
  }
  drawnSa = img.sa;
  bytes($("#k"), img.k, "SK", img.writers.SK, 255);
  bytes($("#syvar"), img.syvar, "SYVAR", img.writers.SYVAR, 32767);
}
function bytes(box, values, name, writers, max) {
  const all = cells(box, values.length, (i) => {
    const c = el("span");
    c.id = name.toLowerCase() + "-" + i;
    c.addEventListener("click", () => {
      const text = prompt(name + i + " = ?", c.dataset.value);
      if (text !== null && text.trim() !== "") write(name + i, Number(text));
    });
    return c;
  });
  for (let i = 0; i < values.length; i++) {
    const c = all[i];
    const who = writers[i];
    if (c.dataset.value === String(values[i]) && c.dataset.who === (who || "")) continue;
    c.dataset.who = who || "";
    c.dataset.value = values[i];
    c.textContent = values[i];
    c.classList.toggle("nz", values[i] !== 0);
    c.title = name + i + " = " + values[i] + (who ? " (last written by " + who + ")" : "");
  }
}
function renderPlc() {
  const box = $("#plc");
  box.replaceChildren();
  const plc = status.plc;
  if (!plc) { box.append(el("p", null, "no PLC logic ([plc] logic)")); return; }
  box.append(el("p", null, plc.state + ", " + plc.scans + " scans, last " + plc.last_scan_us +
                " µs, max " + plc.max_scan_us + " µs, " + plc.overruns + " overruns" +
                (plc.fault ? " — FAULT: " + plc.fault : "")));
  const t = el("table");
  for (const v of plc.variables) {
    const r = el("tr");
    r.append(el("td", null, v.path), el("td", null, v.type),
             el("td", null, JSON.stringify(v.value)));
    t.append(r);
  }
  box.append(t);
}
function renderFieldbus() {
  const box = $("#fieldbus");
  box.replaceChildren();
  const m = status.fieldbus.modbus, c = status.fieldbus.canopen;
  if (m) {
    const where = m.address ? m.address.join(":") : "TLS only";
    box.append(el("p", null, "Modbus TCP " + where + ": " + m.clients.length + " of " +
                  m.max_clients + " clients " + (m.clients.length ? "(" + m.clients.join(", ") + ")" : "")));
  } else box.append(el("p", null, "Modbus off"));
  if (c) {
    box.append(el("p", null, "CANopen node " + c.node_id + ": " + c.nmt + ", heartbeat " +
                  c.heartbeat_ms + " ms" + (c.masters_lost.length ? ", master lost: node " +
                  c.masters_lost.join(", ") : "")));
  } else box.append(el("p", null, "CANopen off"));
}
function describe(ev) {
  const skip = new Set(["seq", "t", "event", "proc", "prog", "line", "n"]);
  const parts = [];
  for (const [k, v] of Object.entries(ev)) {
    if (!skip.has(k)) parts.push(k + " " + (typeof v === "object" ? JSON.stringify(v) : v));
  }
  return parts.join(", ");
}
function logRow(ev) {
  const r = el("tr", ev.event === "alarm" || ev.event === "deadlock" ? "alarm" : "");
  let where = "";
  if (ev.prog) {
    where = ev.prog;
    if (ev.line !== undefined && ev.line !== null) where += ":" + ev.line;
    if (ev.n !== undefined && ev.n !== null) where += " N" + ev.n;
  }
  r.append(el("td", null, ev.seq), el("td", null, ev.t.toFixed(3)), el("td", null, ev.proc),
           el("td", null, ev.event), el("td", null, where), el("td", null, describe(ev)));
  return r;
}
function shown(ev) {
  const proc = $("#filter-proc").value, kind = $("#filter-kind").value;
  return !((proc && String(ev.proc) !== proc) || (kind && ev.event !== kind));
}
// The log is append-only: a batch's rows go on top, the oldest beyond LOG_ROWS go; the whole
// table is built again only when a filter changes.
function appendLog(fresh) {
  const rows = [];
  for (let i = fresh.length - 1; i >= 0 && rows.length < LOG_ROWS; i--) {
    if (shown(fresh[i])) rows.push(logRow(fresh[i]));
  }
  if (!rows.length) return;
  const body = $("#log tbody");
  body.prepend(...rows);
  while (body.childElementCount > LOG_ROWS) body.lastElementChild.remove();
}
function renderLog() {
  const rows = [];
  for (let i = events.length - 1; i >= 0 && rows.length < LOG_ROWS; i--) {
    if (shown(events[i])) rows.push(logRow(events[i]));
  }
  $("#log tbody").replaceChildren(...rows);
}
$("#filter-proc").addEventListener("change", renderLog);
$("#filter-kind").addEventListener("change", renderLog);

let timelineWidth = 0;
window.addEventListener("resize", () => { timelineWidth = 0; timelineDirty = true; });
const COLOURS = { run: "#66bb6a", wait: "#ffb74d", alarm: "#e57373" };
function renderTimeline() {
  const svg = $("#timeline");
  const n = status && status.processes ? status.processes.length : 5;
  // The width is read on a resize only: reading it here would force a layout of the whole
  // page (its log included) on every tick -- 80 ms at 2,000 writes/s.
  if (!timelineWidth) timelineWidth = svg.clientWidth || 900;
  const laneH = 20, top = 14, width = timelineWidth, left = 34;
  svg.setAttribute("height", top + (n + 1) * laneH + 4);
  const end = Math.max(machineNow(), events.length ? events[events.length - 1].t : 0);
  const start = Math.max(0, end - WINDOW_S);
  const x = (t) => left + (width - left - 6) * (t - start) / Math.max(end - start, 1e-6);
  const y = (p) => top + (p === 0 ? n : p - 1) * laneH;
  const parts = [];
  const marks = new Map();  // one mark per 3 pixels: thousands of writes a second stay cheap
  const open = {};  // process -> [state, since]
  const segment = (p, kind, t0, t1) => {
    if (t1 < start) return;
    const r = document.createElementNS(SVG, "rect");
    r.setAttribute("class", "seg " + kind);
    r.setAttribute("x", x(Math.max(t0, start)));
    r.setAttribute("y", y(p) + 3);
    r.setAttribute("width", Math.max(1, x(t1) - x(Math.max(t0, start))));
    r.setAttribute("height", laneH - 6);
    r.setAttribute("fill", COLOURS[kind]);
    parts.push(r);
  };
  for (const ev of events) {
    const p = ev.proc, was = open[p];
    const next = { start: "run", resume: "run", wait: "wait", alarm: "alarm", end: null }[ev.event];
    if (p && next !== undefined) {
      if (was) segment(p, was[0], was[1], ev.t);
      open[p] = next ? [next, ev.t] : null;
    }
    if (ev.t < start) continue;
    if (ev.event === "snd" || ev.event === "exe") {
      const l = document.createElementNS(SVG, "line");
      l.setAttribute("class", "arrow");
      l.setAttribute("x1", x(ev.t)); l.setAttribute("x2", x(ev.t));
      l.setAttribute("y1", y(p) + laneH / 2); l.setAttribute("y2", y(ev.to) + laneH / 2);
      l.setAttribute("stroke", ev.event === "snd" ? "#1565c0" : "#6a1b9a");
      parts.push(l);
    } else if (ev.event === "write" && p === 0) {
      const px = Math.round(x(ev.t) / 3) * 3;  // a mark's radius: closer ones are one
      let m = marks.get(px);
      if (!m) {
        m = document.createElementNS(SVG, "circle");
        m.setAttribute("class", "mark");
        m.setAttribute("cx", px); m.setAttribute("cy", y(0) + laneH / 2); m.setAttribute("r", 3);
        m.setAttribute("fill", "#455a64");
        m.append(document.createElementNS(SVG, "title"));
        marks.set(px, m);
        parts.push(m);
      }
      m.firstChild.textContent = ev.var + " = " + ev.value + " by " + ev.who;  // the last
    }
  }
  for (const [p, was] of Object.entries(open)) if (was) segment(Number(p), was[0], was[1], end);
  for (let p = 0; p <= n; p++) {
    const t = document.createElementNS(SVG, "text");
    t.setAttribute("x", 2); t.setAttribute("y", y(p) + laneH / 2 + 4);
    t.textContent = p === 0 ? "PLC" : "P" + p;
    parts.push(t);
  }
  const axis = document.createElementNS(SVG, "text");
  axis.setAttribute("x", left); axis.setAttribute("y", 10);
  axis.textContent = start.toFixed(1) + " s … " + end.toFixed(1) + " s";
  parts.push(axis);
  svg.replaceChildren(...parts);
  timelineDirty = false;
  timelineAt = performance.now();
}

// ---- the clock --------------------------------------------------------------------------------
// Machine time runs on with the wall clock (times time_scale) whether or not anything
// happens: the header, the timeline's axis and the waits' durations move every second from
// the last status's t, not only when a message comes.
let statusAt = 0, live = false;
function renderClock() {
  const lag = status.lag_s ? " (engine " + status.lag_s.toFixed(3) + " s behind the clock)" : "";
  $("#clock").textContent = "t = " + machineNow().toFixed(1) + " s" +
    (status.held ? " (feed hold)" : "") + lag;
}
function machineNow() {
  if (!status || status.t === undefined) return 0;
  const since = live ? (performance.now() - statusAt) / 1000 : 0;
  return status.t + since * (status.time_scale || 1);
}
function waitFor(span) {
  const s = Math.max(0, machineNow() - Number(span.dataset.since));
  span.textContent = "for " + (s < 60 ? s.toFixed(0) + " s" :
    Math.floor(s / 60) + " min " + (s % 60).toFixed(0).padStart(2, "0") + " s");
}
function tick() {
  if (status && status.t !== undefined) {
    renderClock();
    for (const span of document.querySelectorAll("#lanes .wait .since")) waitFor(span);
  }
  if ($("#pause").checked) return;
  if (timelineDirty || performance.now() - timelineAt >= 1000) renderTimeline();
}
setInterval(tick, TICK_MS);

async function loadPrograms() {
  try {
    const r = await fetch("/api/programs");
    const data = await r.json();
    const box = $("#start-program");
    box.replaceChildren();
    for (const name of data.programs) {
      const o = el("option", null, name);
      o.value = name;
      o.selected = name === data.main;
      box.append(o);
    }
  } catch (e) { /* the stream's reconnect will show that the server is away */ }
}
loadPrograms();
controls();
connect();
