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
// What acts on the cell: disabled while the gateway does not answer, or read-only.
const ACTING = "nav button, nav select, nav input:not(#token), #lanes button, #force-box button, " +
  "#force-box input, #plant-box button, #plant-box input, #plant-box select, #btn-record";
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
// Touched only when something it shows changed (every status message set them again).
let drawnControls = "";
function controls() {
  const off = !live || !status || !status.web || status.web.read_only;
  const record = status && status.record;
  const key = off + "|" + record + "|" + document.querySelectorAll(ACTING).length;
  if (key === drawnControls) return;
  drawnControls = key;
  for (const b of document.querySelectorAll(ACTING)) b.disabled = off;
  const rec = $("#btn-record");
  rec.textContent = record ? "■ Stop recording" : "● Record";
  rec.classList.toggle("on", !!record);
  rec.title = record ? "recording to " + record : rec.dataset.title;
}
function setIfChanged(box, text) { if (box.textContent !== text) box.textContent = text; }
function resetSession() {  // another run: its lanes, programs, events start afresh
  events = [];
  lastSeq = -1;
  status = null;
  session = null;
  pending = {};
  kinds.clear();
  drawnSa = "";
  drawnSaBy = [];
  drawnMarks = drawnNames = drawnTrendNames = "";
  for (const t of trends) t.samples = [];
  for (const box of ["#sa", "#k", "#syvar"]) $(box).cells = null;
  for (const box of ["#lanes", "#log tbody", "#sa", "#k", "#syvar", "#plc", "#fieldbus",
                     "#start-process", "#start-program", "#forced tbody", "#names tbody"]) {
    $(box).replaceChildren();
  }
  for (const box of ["#filter-proc", "#filter-kind"]) $(box).replaceChildren($(box).options[0]);
  timelineReset();
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
async function post(path, body, method) {
  if (!live) { say("the gateway is not answering"); return false; }
  const headers = { "Content-Type": "application/json" };
  if (token) headers.Authorization = "Bearer " + token;
  const r = await fetch(path, { method: method || "POST", headers,
                                body: body === undefined ? undefined : JSON.stringify(body) });
  const answer = await r.json().catch(() => ({}));
  if (r.status === 401) {
    $("#token").hidden = false;
    $("#token").focus();
  }
  say(r.ok ? "" : (answer.error || r.statusText));
  return r.ok;
}
function say(text) { $("#message").textContent = text; }
// Reset (of the cell, a process, an alarm) and writes to the image are asked first: a click
// by mistake must not stop a machine or move an output.
function confirmed(question) { return window.confirm(question); }
for (const b of document.querySelectorAll("button[data-command]")) {
  b.addEventListener("click", () => {
    if (b.dataset.confirm && !confirmed(b.dataset.confirm)) return;
    post("/api/command", { command: b.dataset.command });
  });
}
$("#start-form").addEventListener("submit", (e) => {
  e.preventDefault();
  post("/api/command", { command: "start", program: $("#start-program").value,
                         process: Number($("#start-process").value) });
});
// The commissioning controls: the cell's single block, run to sync, breakpoints,
// the feed override.
$("#single-block").addEventListener("change", () =>
  post("/api/command", { command: "single_block", on: $("#single-block").checked }));
$("#btn-sync").addEventListener("click", () => post("/api/command", { command: "run_to_sync" }));
$("#break-form").addEventListener("submit", (e) => {
  e.preventDefault();
  post("/api/command", { command: "break", at: $("#break-at").value });
});
$("#feed-override").addEventListener("change", () => {
  // An emptied field is no request (Number("") is 0: it would stop the machine's feed).
  const value = $("#feed-override").value.trim();
  if (value !== "") write("FEED_OVERRIDE", Number(value));
});
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
  setIfChanged($("#source"), status.config);
  if (status.web.token && !token) $("#token").hidden = false;
  if (parts.processes) renderLanes();
  if (parts.processes || parts.controls) renderControls();
  if (parts.processes || parts.plc) renderAlarms();
  controls();
  if (parts.image || parts.forced || parts.symbols) renderImage();
  if (parts.forced) renderForced();
  if (parts.plant) renderPlant();
  if (parts.plc) renderPlc();
  if (parts.plc || parts.symbols || parts.image) trendNames();
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
      if (!p.external) {  // this process's own commands: the command of one process
        const controls = el("span", "controls");
        for (const [command, label] of laneButtons) {
          const b = el("button", "lane-" + command, label);
          b.title = label + " process " + p.number;
          b.addEventListener("click", () => {
            if (command === "reset" && !confirmed("Reset process " + p.number + "?")) return;
            post("/api/command", { command, process: p.number });
          });
          controls.append(b);
        }
        lane.append(controls);
      }
      lane.append(el("div", "detail"));
      box.append(lane);
    }
    const state = lane.querySelector(".state");
    // Why it stands, when it does: a breakpoint, single block, M01, an interlock, a feed hold.
    state.textContent = p.state + (p.external ? " (external)" : "") +
      (p.standing ? " · " + p.standing : "");
    state.className = "state s-" + p.state;
    const detail = lane.querySelector(".detail");
    detail.replaceChildren();
    if (p.program) {
      detail.append(el("div", "block", p.program + ":" + p.line + "  " + p.block));
    }
    if (p.wait) {
      const w = p.wait;
      // An auxiliary function's handshake ([nc.aux]) is named as one: the PLC owes an answer.
      const wait = el("div", "wait" + (w.kind === "AUX" ? " aux" : ""),
                      (w.kind === "AUX" ? "handshake: " : "") + w.code + " " + w.reason + " ");
      const since = el("span", "since");  // the tick keeps it going
      since.dataset.since = w.since;
      wait.append(since);
      detail.append(wait);
      waitFor(since);
    }
    if (p.alarm) {
      const a = el("div", "alarm", p.alarm.code + ": " + p.alarm.message + " ");
      const reset = el("button", null, "Reset");
      reset.addEventListener("click", () => {
        if (confirmed("Reset the cell? The alarm is cleared, every process goes to IDLE.")) {
          post("/api/command", { command: "reset" });
        }
      });
      a.append(reset);
      detail.append(a);
    }
    if (!p.external && p.position) {  // where the axes are, the modal feed, the overrides
      const pos = Object.entries(p.position).map(([axis, v]) => axis + " " + v.toFixed(3));
      detail.append(el("span", "pos", pos.join("  ")));
      detail.append(el("span", "feed", "F " + (p.feed === null ? "–" : p.feed) + " mm/min"));
      detail.append(el("span", "override", "override " + p.feed_override + " %" +
                       (p.rapid_override !== 100 ? ", rapid " + p.rapid_override + " %" : "") +
                       (p.single_block ? ", single block" : "")));
    }
    detail.append(el("small", "stats", p.blocks + " blocks, " + p.snd_sent + " SND sent, " +
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
// The image grids: fixed columns, a row label (the index of the row's first cell) and a
// header of column numbers; built once for a size, then only the cells that changed are
// touched.
function grid(box, count, columns, prefix, make) {
  if (box.cells && box.cells.length === count) return box.cells;
  // ARIA's grid is made of rows (role row: a header row of column numbers, then a row of
  // cells led by its index); each row is display: contents, so the cells stay items of
  // the one CSS grid that lays them out.
  const header = el("div", "gridrow");
  header.setAttribute("role", "row");
  const corner = el("span", "col");
  corner.setAttribute("role", "columnheader");
  corner.setAttribute("aria-label", prefix);
  header.append(corner);
  for (let c = 0; c < columns; c++) {
    const h = el("span", "col", String(c));
    h.setAttribute("role", "columnheader");
    header.append(h);
  }
  const items = [header];
  const all = [];
  let row = null;
  for (let i = 0; i < count; i++) {
    if (i % columns === 0) {
      row = el("div", "gridrow");
      row.setAttribute("role", "row");
      const idx = el("span", "idx", prefix + i);
      idx.setAttribute("role", "rowheader");
      row.append(idx);
      items.push(row);
    }
    const c = make(i);
    c.classList.add("cell");
    // Keyboard: one cell of the grid takes the tab (roving), the arrows move it, Enter or
    // Space writes as a click does; a screen reader reads its name and value (aria-label).
    c.setAttribute("role", "gridcell");
    c.tabIndex = i === 0 ? 0 : -1;
    c.setAttribute("aria-label", prefix + i);
    all.push(c);
    row.append(c);
  }
  box.setAttribute("role", "grid");
  box.setAttribute("aria-label", prefix + " (arrows move, Enter writes)");
  box.onkeydown = (e) => {
    const at = all.indexOf(document.activeElement);
    if (at < 0) return;
    const step = { ArrowRight: 1, ArrowLeft: -1, ArrowDown: columns, ArrowUp: -columns,
                   Home: -at, End: all.length - 1 - at }[e.key];
    if (step !== undefined) {
      const next = Math.min(all.length - 1, Math.max(0, at + step));
      all[at].tabIndex = -1;
      all[next].tabIndex = 0;
      all[next].focus();
      e.preventDefault();
    } else if (e.key === "Enter" || e.key === " ") {
      all[at].click();
      e.preventDefault();
    }
  };
  box.replaceChildren(...items);
  box.cells = all;
  return all;
}
function symbolOf(name) {
  const symbol = (status.symbols && status.symbols[name]) || "";
  const comment = symbol && status.symbol_comments && status.symbol_comments[name];
  return comment ? symbol + ": " + comment : symbol;  // [symbols]' comment beside the name
}
function forcedOf(name) {
  return status.forced && name in status.forced ? status.forced[name] : undefined;
}
function note(who, symbol, forced) {
  const said = [];
  if (symbol) said.push(symbol);
  if (who) said.push("last written by " + who);
  if (forced !== undefined) said.push("forced");
  return said.length ? " (" + said.join("; ") + ")" : "";
}
let drawnSa = "", drawnSaBy = [], drawnMarks = "";
function renderImage() {
  const img = status.image;
  const sa = grid($("#sa"), img.sa.length, 16, "SA", (i) => {
    const c = el("span");
    c.id = "sa-" + i;
    c.addEventListener("click", () => {
      const value = c.classList.contains("on") ? 0 : 1;
      const name = "SA" + i + (symbolOf("SA" + i) ? " (" + symbolOf("SA" + i) + ")" : "");
      if (confirmed("Write " + name + " = " + value + " (as web)?")) write("SA" + i, value);
    });
    return c;
  });
  // The names and forces change seldom: when they do, every cell is looked at again.
  const marks = JSON.stringify([status.forced, status.symbols]);
  if (marks !== drawnMarks) { drawnSa = ""; drawnMarks = marks; }
  if (sa.length !== drawnSaBy.length) { drawnSa = ""; drawnSaBy = new Array(sa.length); }
  for (let i = 0; i < img.sa.length; i++) {
    const who = img.writers.SA[i];
    if (img.sa[i] === drawnSa[i] && who === drawnSaBy[i]) continue;  // as drawn
    drawnSaBy[i] = who;
    const on = img.sa[i] === "1";
    const c = sa[i];
    const name = "SA" + i, symbol = symbolOf(name), forced = forcedOf(name);
    c.classList.toggle("on", on);
    c.classList.toggle("named", !!symbol);
    c.classList.toggle("forced", forced !== undefined);
    c.title = name + " = " + (on ? 1 : 0) + note(who, symbol, forced);
    c.setAttribute("aria-label", c.title);
    c.classList.toggle("ext", !!who && who !== "plc");
  }
  drawnSa = img.sa;
  bytes($("#k"), img.k, "SK", img.writers.SK, 255);
  bytes($("#syvar"), img.syvar, "SYVAR", img.writers.SYVAR, 32767);
  renderNames();
}
function bytes(box, values, name, writers, max) {
  const all = grid(box, values.length, 8, name, (i) => {
    const c = el("span");
    c.id = name.toLowerCase() + "-" + i;
    c.addEventListener("click", () => {
      const symbol = symbolOf(name + i);
      const text = prompt("Write " + name + i + (symbol ? " (" + symbol + ")" : "") +
                          " = ? (as web)", c.dataset.value);
      if (text !== null && text.trim() !== "") write(name + i, Number(text));
    });
    return c;
  });
  for (let i = 0; i < values.length; i++) {
    const c = all[i];
    const who = writers[i];
    const symbol = symbolOf(name + i) || symbolOf(name + i + ".IN");
    const forced = forcedOf(name + i) ?? forcedOf(name + i + ".IN");
    const mark = (who || "") + "|" + symbol + "|" + forced;
    if (c.dataset.value === String(values[i]) && c.dataset.mark === mark) continue;
    c.dataset.mark = mark;
    c.dataset.value = values[i];
    c.textContent = values[i];
    c.classList.toggle("nz", values[i] !== 0);
    c.classList.toggle("named", !!symbol);
    c.classList.toggle("forced", forced !== undefined);
    c.title = name + i + " = " + values[i] + note(who, symbol, forced);
    c.setAttribute("aria-label", c.title);
  }
}
// The I/O names of [symbols], each with its variable and value now.
let drawnNames = "";
function renderNames() {
  const rows = Object.entries(status.symbols || {}).map(([v, name]) => {
    const value = valueOf(v);  // (a comment changes with the config only: the key is enough)
    return [name, v, value === undefined ? "" : String(value),
            forcedOf(v) !== undefined ? "F" : ""];
  });
  const key = JSON.stringify(rows);
  if (key === drawnNames) return;
  drawnNames = key;
  const comments = status.symbol_comments || {};
  $("#names tbody").replaceChildren(...rows.map(([name, v, value, f]) => {
    const r = el("tr");
    const cell = el("td", null, name);
    if (comments[v]) cell.title = comments[v];  // the I/O list's comment, as a tooltip
    r.append(cell, el("td", null, v), el("td", null, value), el("td", "forced-mark", f));
    return r;
  }));
}
// The force list: each forced variable, its value and a button that releases it.
function renderForced() {
  const rows = Object.entries(status.forced || {}).map(([v, value]) => {
    const r = el("tr");
    const symbol = symbolOf(v);
    const release = el("button", null, "release");
    release.title = "release " + v;
    release.addEventListener("click", () => post("/api/force", { var: v, value: null }));
    r.append(el("td", "forced-mark", "F"), el("td", null, v + (symbol ? " " + symbol : "")),
             el("td", null, "= " + value), el("td", null));
    r.lastChild.append(release);
    return r;
  });
  $("#forced tbody").replaceChildren(...rows);
  $("#btn-unforce-all").hidden = !rows.length;
  controls();
}
$("#btn-unforce-all").addEventListener("click", () => {
  if (confirmed($("#btn-unforce-all").dataset.confirm)) post("/api/force", undefined, "DELETE");
});
$("#force-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const v = $("#force-var").value.trim(), value = $("#force-value").value;
  if (!v || value === "") { say("force: a variable and a value"); return; }
  if (confirmed("Force " + v + " = " + value + "? It keeps this value whatever writes it, " +
                "until released.")) {
    post("/api/force", { var: v, value: Number(value) });
  }
});
// The plant: each model's state (a fault marked), the faults in force with a button that
// clears each, and a form that injects one -- asked first, as a force is.
// The key a fault kind's one value goes in (docs/plant.md).
const FAULT_VALUE = { stuck: "value", slow: "factor", wire_break: "live_zero",
                      chatter: "period_ms", exception: "code", delay: "ms" };
let drawnPlant = "";
function renderPlant() {
  const plant = status.plant || { models: [], faults: [] };
  const key = JSON.stringify(plant);
  if (key === drawnPlant) return;
  drawnPlant = key;
  $("#plant tbody").replaceChildren(...plant.models.map((m) => {
    const r = el("tr", m.fault ? "faulted" : null);
    r.id = "model-" + m.name;
    const reads = Object.entries(m.reads).map(([k, v]) => k + " " + v).join(", ");
    const writes = Object.entries(m.writes).map(([k, v]) => k + " " + v).join(", ");
    r.title = "reads " + (reads || "nothing") + "; writes " + writes;
    r.append(el("td", null, m.name), el("td", null, m.kind), el("td", null, m.detail),
             el("td", "fault-mark", m.fault || ""));
    return r;
  }));
  $("#faults tbody").replaceChildren(...plant.faults.map((f) => {
    const r = el("tr");
    const clear = el("button", null, "clear");
    clear.title = "clear the faults of " + f.target;
    clear.addEventListener("click", () => post("/api/fault", { clear: f.target }));
    const params = Object.entries(f.params).map(([k, v]) => k + " " + v).join(", ");
    r.append(el("td", "fault-mark", "!"), el("td", null, f.target + ": " + f.kind +
             (params ? " (" + params + ")" : "")), el("td", null, "by " + f.by), el("td", null));
    r.lastChild.append(clear);
    return r;
  }));
  $("#btn-clear-faults").hidden = !plant.faults.length;
  const targets = ["modbus"];
  for (const m of plant.models) {
    targets.push(m.name);
    for (const k of Object.keys(m.writes)) targets.push(m.name + "." + k);
  }
  $("#fault-targets").replaceChildren(...targets.map((t) => {
    const o = el("option");
    o.value = t;
    return o;
  }));
  controls();
}
$("#btn-clear-faults").addEventListener("click", () => {
  if (confirmed($("#btn-clear-faults").dataset.confirm)) post("/api/fault", { clear: "all" });
});
$("#fault-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const target = $("#fault-target").value.trim(), kind = $("#fault-kind").value;
  const value = $("#fault-value").value;
  if (!target) { say("fault: a target"); return; }
  const body = { target, kind };
  if (FAULT_VALUE[kind] && value !== "") body[FAULT_VALUE[kind]] = Number(value);
  if (confirmed("Inject " + kind + " on " + target + (value !== "" && FAULT_VALUE[kind] ?
                " (" + FAULT_VALUE[kind] + " " + value + ")" : "") + "? It stays until cleared.")) {
    post("/api/fault", body);
  }
});
// The PLC's variables, a function block's members and an array's elements one row each
// (a TON's Q and ET as main.t.Q, main.t.ET), so that each can be read and trended.
const PLC_ROWS = 400;
let plcValues = new Map();
function flatten(path, type, value, out) {
  if (out.length >= PLC_ROWS) return;
  if (Array.isArray(value)) {
    const m = /^ARRAY\s*\[\s*(-?\d+)\s*\.\./i.exec(type || "");
    const first = m ? Number(m[1]) : 0;
    const element = (type || "").replace(/^ARRAY\s*\[[^\]]*\]\s*OF\s*/i, "");
    value.forEach((v, i) => flatten(path + "[" + (first + i) + "]", element, v, out));
  } else if (value !== null && typeof value === "object") {
    for (const [k, v] of Object.entries(value)) flatten(path + "." + k, "", v, out);
  } else {
    out.push([path, type, value]);
  }
}
function renderPlc() {
  const box = $("#plc");
  box.replaceChildren();
  const plc = status.plc;
  plcValues = new Map();
  if (!plc) { box.append(el("p", null, "no PLC logic ([plc] logic)")); return; }
  box.append(el("p", null, plc.state + ", " + plc.scans + " scans, last " + plc.last_scan_us +
                " µs, max " + plc.max_scan_us + " µs, " + plc.overruns + " overruns" +
                (plc.fault ? " — FAULT: " + plc.fault : "")));
  const rows = [];
  for (const v of plc.variables) flatten(v.path, v.type, v.value, rows);
  const t = el("table");
  t.id = "plc-vars";
  for (const [path, type, value] of rows) {
    plcValues.set(path.toUpperCase(), value);
    const r = el("tr");
    r.append(el("td", null, path), el("td", null, type),
             el("td", null, typeof value === "boolean" ? (value ? "TRUE" : "FALSE")
                                                       : String(value)));
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
  const r = status.fieldbus.modbus_rtu;
  for (const port of r ? r.ports : []) {  // a serial line, RTU over TCP: each its counters
    const what = port.settings ? "Modbus RTU " + port.port + " (" + port.settings + ")" +
      (port.open ? "" : " not open: " + port.error) : "Modbus RTU over " + port.port;
    box.append(el("p", null, what + ": " + port.frames + " frames, " + port.crc_errors +
                  " CRC errors, " + port.partial + " partial, " + port.exceptions +
                  " exceptions, " + port.other_units + " for other units"));
  }
  if (c) {
    box.append(el("p", null, "CANopen node " + c.node_id + ": " + c.nmt + ", heartbeat " +
                  c.heartbeat_ms + " ms" + (c.masters_lost.length ? ", master lost: node " +
                  c.masters_lost.join(", ") : "")));
  } else box.append(el("p", null, "CANopen off"));
  const u = status.fieldbus.opcua;
  if (u) {  // its endpoint, its clients, what they wrote (docs/opcua.md)
    box.append(el("p", null, "OPC UA " + u.endpoint + " (security " + u.security + ", " +
                  (u.writable.length ? "writes " + u.writable.join(", ") : "read-only") + "): " +
                  u.sessions + " sessions, " + u.subscriptions + " subscriptions, " +
                  u.writes + " writes, " + u.refused + " refused"));
  } else box.append(el("p", null, "OPC UA off"));
}
function describe(ev) {
  const skip = new Set(["seq", "t", "event", "proc", "prog", "line", "n"]);
  const parts = [];
  for (const [k, v] of Object.entries(ev)) {
    if (!skip.has(k)) parts.push(k + " " + (typeof v === "object" ? JSON.stringify(v) : v));
  }
  return parts.join(", ");
}
function logRow(ev, r) {
  if (!r) {
    r = el("tr");
    for (let k = 0; k < 6; k++) r.append(el("td"));
  }
  r.className = ev.event === "alarm" || ev.event === "deadlock" ? "alarm" : "";
  let where = "";
  if (ev.prog) {
    where = ev.prog;
    if (ev.line !== undefined && ev.line !== null) where += ":" + ev.line;
    if (ev.n !== undefined && ev.n !== null) where += " N" + ev.n;
  }
  const c = r.cells;
  setText(c[0], String(ev.seq));
  setText(c[1], ev.t.toFixed(3));
  setText(c[2], String(ev.proc));
  setText(c[3], ev.event);
  setText(c[4], where);
  setText(c[5], describe(ev));
  return r;
}
function setText(cell, text) {  // the cell's text node kept, its text changed
  const node = cell.firstChild;
  if (node) node.data = text;
  else cell.textContent = text;
}
function shown(ev) {
  const proc = $("#filter-proc").value, kind = $("#filter-kind").value;
  return !((proc && String(ev.proc) !== proc) || (kind && ev.event !== kind));
}
// The log is append-only: a batch's rows go on top, the oldest beyond LOG_ROWS go; the whole
// table is built again only when a filter changes.
function appendLog(fresh) {
  const picked = [];
  for (let i = fresh.length - 1; i >= 0 && picked.length < LOG_ROWS; i--) {
    if (shown(fresh[i])) picked.push(fresh[i]);
  }
  if (!picked.length) return;
  const body = $("#log tbody");
  // The rows that would drop off the bottom are filled again and go on top: at 2,000
  // writes a second a page made and threw away 14,000 elements a second, and collecting them
  // made the page's longest tasks.
  const spare = [];
  let last = body.lastElementChild;
  for (let k = body.childElementCount + picked.length - LOG_ROWS; k > 0 && last; k--) {
    spare.push(last);
    last = last.previousElementSibling;
  }
  const rows = picked.map((ev) => logRow(ev, spare.pop()));
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
const STATE_OF = { start: "run", resume: "run", wait: "wait", alarm: "alarm", end: null };
const MARK_S = WINDOW_S / 300;  // writes closer than this share one mark (and its tooltip)
// The timeline is drawn incrementally: what an event adds goes into a group in machine-time
// coordinates once; a tick only moves and scales the group (its transform), stretches the
// open bars to now and drops what has scrolled out. (Rebuilding it from 3,000 events four
// times a second made a page at 2,000 writes/s throw away thousands of elements a second.)
const tl = { lanes: -1, seq: 0, open: {}, items: [], marks: new Map(), group: null, axis: null };
function timelineReset() {
  tl.lanes = -1;  // the next tick draws it afresh
}
function timelineStart(svg, n, laneH, top) {
  tl.lanes = n;
  tl.seq = 0;
  tl.open = {};
  tl.items = [];
  tl.marks = new Map();
  // A nested svg clips the bars to the plot (a bar that began before the window would run
  // over the lane names).
  tl.plot = document.createElementNS(SVG, "svg");
  tl.plot.setAttribute("x", 34);
  tl.plot.setAttribute("height", top + (n + 1) * laneH + 4);
  tl.group = document.createElementNS(SVG, "g");
  tl.plot.append(tl.group);
  const parts = [tl.plot];
  for (let p = 0; p <= n; p++) {
    const t = document.createElementNS(SVG, "text");
    t.setAttribute("x", 2); t.setAttribute("y", laneY(p, n, laneH, top) + laneH / 2 + 4);
    t.textContent = p === 0 ? "PLC" : "P" + p;
    parts.push(t);
  }
  tl.axis = document.createElementNS(SVG, "text");  // the last child: the axis
  tl.axis.setAttribute("x", 34); tl.axis.setAttribute("y", 10);
  parts.push(tl.axis);
  svg.replaceChildren(...parts);
}
function laneY(p, n, laneH, top) { return top + (p === 0 ? n : p - 1) * laneH; }
function timelineAdd(ev, n, laneH, top) {
  const p = ev.proc, t = ev.t;
  const next = STATE_OF[ev.event];
  if (p && p <= n && next !== undefined) {
    const was = tl.open[p];
    if (was) {
      was.rect.setAttribute("width", Math.max(t - was.t0, WINDOW_S / 1500));
      tl.items.push([t, was.rect]);
    }
    tl.open[p] = null;
    if (next) {
      const r = document.createElementNS(SVG, "rect");
      r.setAttribute("class", "seg " + next);
      r.setAttribute("x", t);
      r.setAttribute("y", laneY(p, n, laneH, top) + 3);
      r.setAttribute("width", WINDOW_S / 1500);
      r.setAttribute("height", laneH - 6);
      r.setAttribute("fill", COLOURS[next]);
      tl.group.append(r);
      tl.open[p] = { t0: t, rect: r };
    }
  }
  if ((ev.event === "snd" || ev.event === "exe") && ev.to <= n) {
    const l = document.createElementNS(SVG, "line");
    l.setAttribute("class", "arrow");
    l.setAttribute("x1", t); l.setAttribute("x2", t);
    l.setAttribute("y1", laneY(p, n, laneH, top) + laneH / 2);
    l.setAttribute("y2", laneY(ev.to, n, laneH, top) + laneH / 2);
    l.setAttribute("stroke", ev.event === "snd" ? "#1565c0" : "#6a1b9a");
    l.setAttribute("vector-effect", "non-scaling-stroke");
    tl.group.append(l);
    tl.items.push([t, l]);
  } else if (ev.event === "write" && p === 0) {
    const bucket = Math.floor(t / MARK_S);
    let m = tl.marks.get(bucket);
    if (!m) {
      m = document.createElementNS(SVG, "rect");
      m.setAttribute("class", "mark");
      m.setAttribute("x", bucket * MARK_S); m.setAttribute("width", MARK_S);
      m.setAttribute("y", laneY(0, n, laneH, top) + laneH / 2 - 3); m.setAttribute("height", 6);
      m.setAttribute("fill", "#455a64");
      m.append(document.createElementNS(SVG, "title"));
      m.dataset.bucket = bucket;
      tl.marks.set(bucket, m);
      tl.group.append(m);
      tl.items.push([(bucket + 1) * MARK_S, m]);
    }
    m.firstChild.textContent = ev.var + " = " + ev.value + " by " + ev.who;  // the last
  }
}
function renderTimeline() {
  const svg = $("#timeline");
  const n = status && status.processes ? status.processes.length : 5;
  // The width is read on a resize only: reading it here would force a layout of the whole
  // page (its log included) on every tick -- 80 ms at 2,000 writes/s.
  if (!timelineWidth) timelineWidth = svg.clientWidth || 900;
  const laneH = 20, top = 14, width = timelineWidth, left = 34;
  if (tl.lanes !== n) {
    svg.setAttribute("height", top + (n + 1) * laneH + 4);
    timelineStart(svg, n, laneH, top);
  }
  // The events not drawn yet (the page keeps them in seq order).
  let i = events.length;
  while (i > 0 && events[i - 1].seq > tl.seq) i--;
  for (; i < events.length; i++) timelineAdd(events[i], n, laneH, top);
  if (events.length) tl.seq = Math.max(tl.seq, events[events.length - 1].seq);
  const end = Math.max(machineNow(), events.length ? events[events.length - 1].t : 0);
  const start = Math.max(0, end - WINDOW_S);
  const k = (width - left - 6) / Math.max(end - start, 1e-6);
  tl.plot.setAttribute("width", width - left);
  tl.group.setAttribute("transform", "matrix(" + k + ",0,0,1," + (-start * k) + ",0)");
  for (const was of Object.values(tl.open)) {
    if (was) was.rect.setAttribute("width", Math.max(end - was.t0, WINDOW_S / 1500));
  }
  // What ended before the window starts goes (in the order it was drawn: by time).
  let gone = 0;
  while (gone < tl.items.length && tl.items[gone][0] < start) {
    const item = tl.items[gone++][1];
    if (item.dataset.bucket !== undefined) tl.marks.delete(Number(item.dataset.bucket));
    item.remove();
  }
  if (gone) tl.items.splice(0, gone);
  tl.axis.textContent = start.toFixed(1) + " s … " + end.toFixed(1) + " s";
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
  setIfChanged($("#clock"), "t = " + machineNow().toFixed(1) + " s" +
    (status.standing ? " (" + status.standing + ")" : "") + lag);
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
  if (status && status.t !== undefined && trends.length) {
    const now = machineNow();
    sampleTrends(now);
    renderTrends(now);
  }
  if ($("#pause").checked) return;
  if (timelineDirty || performance.now() - timelineAt >= 1000) renderTimeline();
}
setInterval(tick, TICK_MS);

// ---- trends -----------------------------------------------------------------------------------
// Chosen variables sampled on the clock tick (the status the page holds), the last TREND_S
// seconds of machine time drawn as lines over a time axis.
const TREND_S = 60, TREND_MAX = 8;
const TREND_COLOURS = ["#1e88e5", "#e53935", "#43a047", "#fb8c00", "#8e24aa", "#00897b",
                       "#6d4c41", "#d81b60"];
const trends = [];  // {name, samples: [[t, value]]}
function valueOf(name) {
  if (!status || !status.image) return undefined;
  const upper = name.trim().toUpperCase();
  let m = /^SA(\d+)$/.exec(upper);
  if (m) return status.image.sa[Number(m[1])] === undefined ? undefined
                                                           : Number(status.image.sa[Number(m[1])]);
  m = /^SK(\d+)$/.exec(upper);
  if (m) return status.image.k[Number(m[1])];
  m = /^SYVAR(\d+)$/.exec(upper);
  if (m) return status.image.syvar[Number(m[1])];
  for (const [v, symbol] of Object.entries(status.symbols || {})) {
    if (symbol.toUpperCase() === upper) return valueOf(v.replace(/\.IN$/, ""));
  }
  const plc = plcValues.get(upper);
  if (typeof plc === "boolean") return plc ? 1 : 0;
  return typeof plc === "number" ? plc : undefined;
}
let drawnTrendNames = "";
function trendNames() {  // what the trend field offers
  const names = [...Object.values(status.symbols || {}), ...plcValues.keys()].filter(
    (n) => valueOf(n) !== undefined);
  const key = names.join(",");
  if (key === drawnTrendNames) return;
  drawnTrendNames = key;
  $("#trend-names").replaceChildren(...names.map((n) => { const o = el("option"); o.value = n; return o; }));
}
$("#trend-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const name = $("#trend-var").value.trim();
  if (!name) return;
  if (valueOf(name) === undefined) { say("trend: no variable " + name); return; }
  if (trends.some((t) => t.name.toUpperCase() === name.toUpperCase())) return;
  if (trends.length >= TREND_MAX) { say("trend: at most " + TREND_MAX + " variables"); return; }
  trends.push({ name, samples: [] });
  $("#trend-var").value = "";
  say("");
  renderTrendLegend();
});
function renderTrendLegend() {
  $("#trend-legend").replaceChildren(...trends.map((t, i) => {
    const item = el("span", "item");
    item.dataset.name = t.name;
    const swatch = el("span", "swatch");
    swatch.style.background = TREND_COLOURS[i];
    const remove = el("button", null, "\u00d7");
    remove.title = "remove " + t.name;
    remove.addEventListener("click", () => { trends.splice(trends.indexOf(t), 1); renderTrendLegend(); });
    item.append(swatch, el("span", "value", t.name), remove);
    return item;
  }));
}
function sampleTrends(now) {
  for (const t of trends) {
    const v = valueOf(t.name);
    if (v === undefined) continue;
    t.samples.push([now, v]);
    while (t.samples.length && t.samples[0][0] < now - TREND_S) t.samples.shift();
  }
}
let trendWidth = 0;
window.addEventListener("resize", () => { trendWidth = 0; });
function renderTrends(now) {
  const svg = $("#trend");
  if (!trendWidth) trendWidth = svg.clientWidth || 600;
  const width = trendWidth, height = 150, left = 44, right = 8, top = 8, bottom = 20;
  const start = Math.max(0, now - TREND_S);  // from 0 until a minute has passed
  // Each trend on a scale of its own (a BOOL beside a 0..2000 value would be flat on a
  // shared one): its own min..max, said in its legend; the axis says the first trend's.
  const range = (t) => {
    let lo = Infinity, hi = -Infinity;
    for (const [, v] of t.samples) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (lo === Infinity) { lo = 0; hi = 1; }
    if (hi === lo) { hi += 1; lo -= hi === 1 ? 0 : 1; }
    return [lo, hi];
  };
  const ranges = trends.map(range);
  const [lo, hi] = ranges.length ? ranges[0] : [0, 1];
  const x = (t) => left + (width - left - right) * (t - start) / TREND_S;
  const yOf = ([l, h]) => (v) => top + (height - top - bottom) * (1 - (v - l) / (h - l));
  const parts = [];
  const line = (x1, y1, x2, y2, cls) => {
    const l = document.createElementNS(SVG, "line");
    l.setAttribute("class", cls);
    l.setAttribute("x1", x1); l.setAttribute("y1", y1); l.setAttribute("x2", x2); l.setAttribute("y2", y2);
    parts.push(l);
  };
  const label = (tx, ty, text, anchor, cls) => {
    const t = document.createElementNS(SVG, "text");
    t.setAttribute("x", tx); t.setAttribute("y", ty);
    t.setAttribute("text-anchor", anchor);
    if (cls) t.setAttribute("class", cls);
    t.textContent = text;
    parts.push(t);
  };
  line(left, height - bottom, width - right, height - bottom, "axis");
  line(left, top, left, height - bottom, "axis");
  for (let k = 0; k <= 6; k++) {  // a tick every 10 s of machine time
    const t = Math.ceil(start / 10) * 10 + k * 10;
    if (t > start + TREND_S) break;
    line(x(t), height - bottom, x(t), height - bottom + 3, "axis");
    // The last label ends at the right edge rather than past it.
    label(x(t), height - 6, t.toFixed(0) + " s", x(t) > width - right - 20 ? "end" : "middle",
          "tick");
  }
  label(left - 4, top + 8, String(+hi.toFixed(3)), "end");
  label(left - 4, height - bottom, String(+lo.toFixed(3)), "end");
  trends.forEach((t, i) => {
    if (!t.samples.length) return;
    const y = yOf(ranges[i]);
    const pl = document.createElementNS(SVG, "polyline");
    // A step line: a value holds until the next sample.
    const points = [];
    let prev = null;
    for (const [ts, v] of t.samples) {
      if (prev !== null) points.push(x(ts).toFixed(1) + "," + y(prev).toFixed(1));
      points.push(x(ts).toFixed(1) + "," + y(v).toFixed(1));
      prev = v;
    }
    pl.setAttribute("points", points.join(" "));
    pl.setAttribute("stroke", TREND_COLOURS[i]);
    pl.dataset.name = t.name;
    parts.push(pl);
  });
  svg.replaceChildren(...parts);
  for (const item of document.querySelectorAll("#trend-legend .item")) {
    const t = trends.find((tr) => tr.name === item.dataset.name);
    const last = t && t.samples.length ? t.samples[t.samples.length - 1][1] : "";
    const [tlo, thi] = t ? range(t) : [0, 1];
    item.querySelector(".value").textContent = item.dataset.name + " = " + last +
      (trends.length > 1 ? " (" + +tlo.toFixed(3) + ".." + +thi.toFixed(3) + ")" : "");
  }
}

// ---- record, theme ------------------------------------------------------------------------------
$("#btn-record").dataset.title = $("#btn-record").title;
$("#btn-record").addEventListener("click", async () => {
  await post("/api/record", { on: !(status && status.record) });
});
const THEMES = ["auto", "dark", "light"];
function setTheme(theme) {
  if (theme === "auto") delete document.documentElement.dataset.theme;
  else document.documentElement.dataset.theme = theme;
  $("#theme").textContent = { auto: "◐ auto", dark: "● dark", light: "○ light" }[theme];
  localStorage.setItem("ncgate-theme", theme);
}
setTheme(THEMES.includes(localStorage.getItem("ncgate-theme")) ? localStorage.getItem("ncgate-theme") : "auto");
$("#theme").addEventListener("click", () => {
  const now = localStorage.getItem("ncgate-theme") || "auto";
  setTheme(THEMES[(THEMES.indexOf(now) + 1) % THEMES.length]);
});

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
// The commands of one process, as the command table names them (GET /api/commands): asked
// before the stream starts, so the first lanes drawn have their buttons.
let laneButtons = [];
async function loadCommands() {
  try {
    const r = await fetch("/api/commands");
    laneButtons = (await r.json()).lane;
  } catch (e) { /* the stream's reconnect will show that the server is away */ }
}
loadPrograms();
controls();
loadCommands().finally(connect);
