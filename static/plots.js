// Plots of the selected vehicle's telemetry: any numeric field against time, with its events (mode changes,
// arming, commands and their ACKs, messages, the onboard agent's phases) as markers on the same axis. Live,
// the axis is the history the station kept (GET /api/vehicles/{id}/history); in a replay it is the whole
// log (GET /api/replay/timeline), with the replay's time marked, and clicking the plot or a marker seeks the
// replay there (which needs the operator token, as the replay's own controls do).

import { $, EVENTS, REPLAY_SIGN_IN_HINT, api, el, fmt, getJson, isNum, on } from "./common.js";

const POLL_MS = 2000;
const KINDS = new Set(["mode", "armed", "command", "ack", "message", "agent", "crash", "near miss"]);
const LOG_SHOWN = 300;  // events in the log below the plot, newest first

const canvas = $("#plot");
const ctx = canvas.getContext("2d");
let mode = "live";
let replay = null;          // the replay status from the stream
let timeline = null;        // the replay's whole-log timeline (or null while it is scanned)
let timelineName = null;
let history = null;         // the shown vehicle's history: {t, series, units, events}
let present = new Set();    // the system ids the latest status frame holds
let origin = 0;             // time 0 of the axis (the log's start in a replay)
let span = [0, 1];          // the axis's range, relative to origin
const plots = { get field() { return $("#plot-field").value; }, get span() { return span; } };
window.plots = plots;       // for tests: what the plot shows

function hint(text) {
  $("#plot-hint").textContent = text;
}

async function refresh() {
  const sysid = window.selectedVehicle;
  $("#plots").hidden = !Number.isInteger(sysid);
  if (!Number.isInteger(sysid) || document.hidden) return;
  if (mode === "replay") {
    const name = `${replay && replay.name}|${sysid}`;  // the selected vehicle's timeline of this log
    if (!timeline || !timeline.ready || timelineName !== name) {
      const found = await getJson(`/api/replay/timeline?sysid=${sysid}`);
      if (found && typeof found === "object") {
        timeline = found;
        timelineName = name;
      }
    }
    if (timeline && timeline.error) hint(`The log's timeline could not be read: ${timeline.error}`);
    else if (!timeline || !timeline.ready) hint("Reading the whole log for its timeline…");
    else hint("Click the plot or a marker to go there in the replay");
    history = timeline && timeline.vehicles ? timeline.vehicles[String(sysid)] || null : null;
    origin = timeline && isNum(timeline.start) ? timeline.start : 0;
    span = [0, timeline && isNum(timeline.duration) ? Math.max(timeline.duration, 0.1) : 1];
  } else {
    // asked for only while the station holds the vehicle (a replay's start clears them, and the browser logs
    // every 404 as an error in the console)
    history = present.has(sysid) ? await getJson(`/api/vehicles/${sysid}/history?limit=600`) : null;
    const t = history && Array.isArray(history.t) ? history.t : [];
    origin = t.length ? t[t.length - 1] : 0;  // live: seconds before the latest sample
    span = t.length > 1 ? [t[0] - origin, 0] : [-1, 0];
    hint("");
  }
  renderFields();
  renderEvents();
  draw();
}

function renderFields() {
  const select = $("#plot-field");
  const names = history && history.series ? Object.keys(history.series) : [];
  const key = names.join("|");
  if (select.dataset.key === key) return;
  select.dataset.key = key;
  const previous = select.value || "altitude";
  select.replaceChildren(...names.map((name) => {
    const unit = history.units && history.units[name];
    const option = el("option", "", unit ? `${name} (${unit})` : name);
    option.value = name;
    return option;
  }));
  if (names.includes(previous)) select.value = previous;
}

function xOf(t, width) {
  return ((t - origin - span[0]) / (span[1] - span[0])) * width;
}

function draw() {
  const rect = canvas.getBoundingClientRect();
  const ratio = window.devicePixelRatio || 1;
  const w = Math.max(1, rect.width), h = Math.max(1, rect.height);
  if (canvas.width !== Math.round(w * ratio)) canvas.width = Math.round(w * ratio);
  if (canvas.height !== Math.round(h * ratio)) canvas.height = Math.round(h * ratio);
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.fillStyle = "#0b0e11";
  ctx.fillRect(0, 0, w, h);
  const field = $("#plot-field").value;
  const t = history && Array.isArray(history.t) ? history.t : [];
  const values = history && history.series && Array.isArray(history.series[field]) ? history.series[field] : [];
  const finite = values.filter(isNum);
  ctx.font = "10px system-ui, sans-serif";
  ctx.fillStyle = "#8d99a6";
  if (!finite.length) {
    ctx.fillText("no samples yet", 8, h / 2);
    $("#plot-value").textContent = "";
    return;
  }
  let lo = Math.min(...finite), hi = Math.max(...finite);
  if (hi - lo < 1e-6) { lo -= 1; hi += 1; }
  const pad = (hi - lo) * 0.08;
  lo -= pad; hi += pad;
  const yOf = (v) => h - 14 - ((v - lo) / (hi - lo)) * (h - 24);
  ctx.strokeStyle = "#2b333d";
  ctx.lineWidth = 1;
  for (const f of [0, 0.5, 1]) {
    const y = yOf(lo + (hi - lo) * f);
    ctx.beginPath();
    ctx.moveTo(0, y);
    ctx.lineTo(w, y);
    ctx.stroke();
    ctx.fillText(fmt(lo + (hi - lo) * f), 3, y - 2);
  }
  ctx.strokeStyle = "#5fb3c4";
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  let pen = false;
  for (let i = 0; i < t.length; i++) {
    if (!isNum(values[i])) { pen = false; continue; }
    const x = xOf(t[i], w), y = yOf(values[i]);
    if (pen) ctx.lineTo(x, y); else ctx.moveTo(x, y);
    pen = true;
  }
  ctx.stroke();
  ctx.fillStyle = "#8d99a6";
  ctx.fillText(`${span[0].toFixed(0)} s`, 3, h - 3);
  const end = `${span[1].toFixed(0)} s`;
  ctx.fillText(end, w - ctx.measureText(end).width - 3, h - 3);
  let current = finite[finite.length - 1];
  if (mode === "replay" && replay && isNum(replay.time)) {  // the replay's time: a line, and the value there
    const x = xOf(origin + replay.time, w);
    ctx.strokeStyle = "#b48ce8";
    ctx.beginPath();
    ctx.moveTo(x, 0);
    ctx.lineTo(x, h);
    ctx.stroke();
    const i = t.findIndex((s) => s >= origin + replay.time);
    current = values[i < 0 ? t.length - 1 : i];
  }
  const unit = history.units && history.units[field] ? ` ${history.units[field]}` : "";
  $("#plot-value").textContent = isNum(current) ? `${fmt(current)}${unit}` : "";
}

/** The events the filters let through: at most the chosen severity (an event without one counts as info, 6), from
 * a source that is ticked. */
function filtered(events) {
  const worst = Number($("#event-severity").value);
  const sources = new Set([...document.querySelectorAll(".event-source:checked")].map((box) => box.value));
  return events.filter((e) => e && isNum(e.t) && (isNum(e.severity) ? e.severity : 6) <= worst
    && sources.has(e.source || "autopilot"));
}

function renderLog(events) {
  const list = $("#event-log");
  list.replaceChildren(...events.slice(-LOG_SHOWN).reverse().map((e) => {
    const level = isNum(e.severity) ? (e.severity <= 3 ? "severe" : e.severity <= 4 ? "warning" : "") : "";
    const li = el("li", level);
    li.dataset.source = e.source || "autopilot";
    li.append(el("time", "msg-time", `${fmt(e.t - origin)} s`), el("span", "event-source-tag", li.dataset.source),
      el("span", "msg-text", String(e.text ?? "")));
    return li;
  }));
  if (!events.length) list.append(el("li", "none", "no events match"));
  const counted = history && Array.isArray(history.counted) ? history.counted : [];
  $("#event-counted").textContent = counted.length ? `Counted, not listed: ${counted.map((c) =>
    `${c.text} × ${c.count} (${c.source})`).join(", ")}` : "";
}

function renderEvents() {
  const box = $("#plot-events");
  const all = history && Array.isArray(history.events) ? history.events : [];
  const events = filtered(all);
  const key = JSON.stringify([span, origin, all.length, all.length && all[all.length - 1].t, $("#event-severity").value,
    [...document.querySelectorAll(".event-source:checked")].map((b) => b.value),
    history && Array.isArray(history.counted) ? history.counted.map((c) => c.count) : []]);
  if (box.dataset.key === key) return;
  box.dataset.key = key;
  renderLog(events);
  box.replaceChildren(...events.map((e) => {
    const at = (e.t - origin - span[0]) / (span[1] - span[0]);
    const marker = el("button");
    marker.type = "button";
    const kind = (KINDS.has(e.kind) ? e.kind : "message").replace(" ", "-");
    const level = isNum(e.severity) ? (e.severity <= 3 ? " severe" : e.severity <= 4 ? " warning" : "") : "";
    marker.className = `event-marker ${kind}${level}`;
    marker.style.left = `${Math.max(0, Math.min(1, at)) * 100}%`;
    marker.dataset.t = String(e.t - origin);
    marker.title = `${fmt(e.t - origin)} s · ${String(e.text ?? "")}`;
    marker.setAttribute("aria-label", marker.title);
    marker.addEventListener("click", () => {
      hint(marker.title);
      seek(e.t - origin);
    });
    return marker;
  }));
}

async function seek(seconds) {
  if (mode !== "replay") return;
  const to = Math.max(0, Math.min(span[1], seconds));
  const { status } = await api("POST", "/api/replay/control", { seek: to });
  if (status === 401) hint(REPLAY_SIGN_IN_HINT);
  else if (status !== 200) hint(`Seek failed (HTTP ${status})`);
  else hint(`Went to ${fmt(to)} s`);
}

canvas.addEventListener("click", (event) => {
  const rect = canvas.getBoundingClientRect();
  seek(span[0] + ((event.clientX - rect.left) / rect.width) * (span[1] - span[0]));
});
$("#plot-field").addEventListener("change", draw);
for (const control of [$("#event-severity"), ...document.querySelectorAll(".event-source")]) {
  control.addEventListener("change", renderEvents);
}
window.addEventListener("resize", draw);
on(EVENTS.selected, () => {
  history = null;
  refresh();
});
on(EVENTS.status, (msg) => {
  const next = msg.mode === "replay" ? "replay" : "live";
  replay = msg.replay || null;
  present = new Set((Array.isArray(msg.vehicles) ? msg.vehicles : []).map((v) => v && v.sysid));
  if (next !== mode) {
    mode = next;
    timeline = null;
    refresh();
  } else if (mode === "replay") {
    draw();
  }
});
setInterval(refresh, POLL_MS);
