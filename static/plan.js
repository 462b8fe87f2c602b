// The plan view: a mission for the selected vehicle. With "Edit on map" pressed, a click on the 2D map (or on
// the ground in the 3D view, "station-target") adds a waypoint (a copter's first click adds its take-off at
// home first) and a waypoint dragged there moves it ("map2d-click", "plan-move" from map2d.js); each item's
// action, altitude, speed and hold are set in the table. The station checks every leg against the scene
// (POST /api/plan/check: a leg through a building is red on the map and named here), reads and writes the
// files (QGC WPL 110 and QGroundControl .plan, so a hostile file meets the same checks as an upload), and
// uploads through the MAVLink mission protocol (PUT /api/vehicles/{id}/mission, its items counted by
// .../mission/progress, the vehicle's MISSION_ACK shown). "Fly (AUTO)" arms if needed, sets AUTO and starts
// the uploaded mission (the station's "auto" action); the item being flown is marked, from the vehicle's
// MISSION_CURRENT in the status frames.

import {
  $, EVENTS, api, apiText, commandBlocker, detailText, el, emit, fmt, getJson, isNum, on, postWithAck, setEnabled,
  setText, showAck, showHint,
} from "./common.js";

const ACTIONS = [["takeoff", "Take off"], ["waypoint", "Waypoint"], ["loiter", "Loiter (time)"], ["land", "Land"],
                 ["rtl", "Return to launch"]];
const CLIMB_RATE = 1.0;  // m/s up or down, for the time estimate (a copter's take-off and landing)
const DRAIN_WINDOW_S = 120;  // the battery's drain is measured over the last this many seconds of history

let items = [];        // [{action, x, y, alt, speed, hold}]
let legs = [];         // the station's check of each item's leg: [{length, blocked, hit, object}]
let selected = null;   // index of the item picked in the table or on the map
let editing = false;
let vehicles = [];
let auth = "none";
let mode = "live";
let checkSeq = 0;
let drain = null;      // % per second the selected vehicle's battery lost lately (null: not known yet)
window.plan = { get items() { return items; }, get legs() { return legs; } };  // for tests

function vehicle() {
  return vehicles.find((v) => v.sysid === window.selectedVehicle) || null;
}

function home() {
  const v = vehicle();
  if (v && v.home && isNum(v.home.x) && isNum(v.home.y)) return [v.home.x, v.home.y];
  if (v && v.position && isNum(v.position.x)) return [v.position.x, v.position.y];
  return [0, 0];
}

/** The mission's sequence number of each plan item (home is 0; a speed is a DO_CHANGE_SPEED item of its own). */
function sequenceNumbers() {
  let seq = 0, speed = null;
  return items.map((p) => {
    if (isNum(p.speed) && p.speed !== speed) { seq += 1; speed = p.speed; }
    seq += 1;
    return seq;
  });
}

function currentIndex() {
  const v = vehicle();
  const current = v && v.mission && v.mission.current;
  if (!isNum(current) || !v.mode || v.mode !== "AUTO") return null;
  const index = sequenceNumbers().indexOf(current);
  return index >= 0 ? index : null;
}

function planBody() {
  return { home: home(), items: items.map((p) => ({ action: p.action, x: p.x, y: p.y, alt: p.alt,
                                                     speed: isNum(p.speed) ? p.speed : null, hold: p.hold || 0 })) };
}

function publish() {
  emit(EVENTS.plan, { editing, items, legs, home: home(), selected, current: currentIndex() });
}

// ---- the table ------------------------------------------------------------------------------------------
function numberInput(value, field, index, attrs) {
  const input = el("input", "plan-number");
  input.type = "number";
  Object.assign(input, attrs);
  input.value = isNum(value) ? String(value) : "";
  input.dataset.field = field;
  input.setAttribute("aria-label", `${field} of item ${index + 1}`);
  return input;
}

function renderItems() {
  const seqs = sequenceNumbers();
  const rows = items.map((p, i) => {
    const row = el("tr", i === selected ? "selected" : "");
    row.dataset.index = String(i);
    const select = el("select");
    select.dataset.field = "action";
    select.setAttribute("aria-label", `action of item ${i + 1}`);
    for (const [value, label] of ACTIONS) {
      const option = el("option", "", label);
      option.value = value;
      select.append(option);
    }
    select.value = p.action;
    const legCell = el("td", "leg");
    const remove = el("button", "btn btn-small plan-delete", "✕");
    remove.type = "button";
    remove.setAttribute("aria-label", `Delete item ${i + 1}`);
    const number = el("td", "seq", String(i + 1));
    number.title = `mission item ${seqs[i]}`;
    row.append(number, el("td"), el("td"), el("td"), el("td"), legCell, el("td"));
    row.children[1].append(select);
    row.children[2].append(numberInput(p.alt, "alt", i, { min: 0, max: 1000, step: 0.5 }));
    row.children[3].append(numberInput(p.speed, "speed", i, { min: 0.1, max: 100, step: 0.1, placeholder: "–" }));
    row.children[4].append(numberInput(p.hold, "hold", i, { min: 0, max: 86400, step: 1 }));
    row.children[6].append(remove);
    return row;
  });
  $("#plan-items").replaceChildren(...rows);
  $("#plan-empty").hidden = items.length > 0;
  renderLegs();
}

/** Each row's leg as the station checked it: only these cells change when its answer comes, so that a field
 * the operator is typing in meanwhile keeps what was typed. */
function renderLegs() {
  for (const row of $("#plan-items").children) {
    const i = Number(row.dataset.index), leg = legs[i], cell = row.querySelector("td.leg");
    cell.classList.toggle("blocked", Boolean(leg && leg.blocked));
    setText(cell, leg ? `${fmt(leg.length)} m${leg.blocked ? " ✕" : ""}` : "…");
    cell.title = leg && leg.blocked ? blockedText(i, leg) : "";
  }
}

function blockedText(i, leg) {
  const at = Array.isArray(leg.hit) ? ` at (${fmt(leg.hit[0])}, ${fmt(leg.hit[1])}, ${fmt(leg.hit[2])})` : "";
  return `Leg to item ${i + 1} goes through ${leg.object || "the scene"}${at}`;
}

function duration(seconds) {
  if (!isNum(seconds)) return "–";
  const s = Math.round(seconds);
  return s >= 60 ? `${Math.floor(s / 60)} min ${String(s % 60).padStart(2, "0")} s` : `${s} s`;
}

/** Per-leg lengths come from the station's check; the time adds the holds and the climbs at CLIMB_RATE. */
function renderSummary() {
  const cruise = Number($("#plan-cruise").value) > 0 ? Number($("#plan-cruise").value) : 2.5;
  let total = 0, time = 0, speed = cruise, known = legs.length === items.length;
  items.forEach((p, i) => {
    if (isNum(p.speed)) speed = p.speed;
    const leg = legs[i];
    if (!leg) { known = false; return; }
    total += leg.length;
    const climb = p.action === "takeoff" ? p.alt : 0;
    time += (leg.length - climb) / speed + climb / CLIMB_RATE + (p.hold || 0);
    if (p.action === "land") time += Math.max(p.alt || 0, (items[i - 1] || {}).alt || 0) / CLIMB_RATE;
  });
  const v = vehicle();
  const remaining = v && v.battery && isNum(v.battery.remaining) && v.battery.remaining >= 0 ? v.battery.remaining
    : null;
  const endurance = remaining !== null && drain > 0 ? remaining / drain : null;
  let battery = remaining === null ? "battery unknown" : `battery ${Math.round(remaining)} %`;
  if (endurance !== null) battery += `, about ${duration(endurance)} of flight left`;
  else if (remaining !== null) battery += " (its drain is not known yet)";
  const summary = $("#plan-summary");
  summary.classList.toggle("bad", endurance !== null && time > endurance * 0.8);
  setText(summary, items.length ? `${items.length} items · ${known ? fmt(total) : "…"} m · about ${
    known ? duration(time) : "…"} · ${battery}${endurance !== null && time > endurance * 0.8
    ? ": not enough for this plan with a fifth in reserve" : ""}` : "");
  summary.dataset.distance = known ? String(total) : "";
  summary.dataset.seconds = known ? String(time) : "";
  const blocked = legs.map((leg, i) => (leg && leg.blocked ? blockedText(i, leg) : null)).filter(Boolean);
  $("#plan-blocked").hidden = !blocked.length;
  setText($("#plan-blocked"), blocked.join("; "));
}

/** The battery's drain over the last DRAIN_WINDOW_S of the vehicle's history (% per second), or null. */
async function measureDrain() {
  const v = vehicle();
  if (!v || mode !== "live") { drain = null; return; }
  const history = await getJson(`/api/vehicles/${v.sysid}/history?limit=600`);
  const t = history && Array.isArray(history.t) ? history.t : [];
  const series = history && history.series && history.series["battery remaining"];
  const samples = Array.isArray(series) ? t.map((s, i) => [s, series[i]]).filter(([s, r]) => isNum(s) && isNum(r)) : [];
  if (samples.length < 2) { drain = null; return; }
  const end = samples[samples.length - 1];
  const start = samples.find(([s]) => s >= end[0] - DRAIN_WINDOW_S);
  const span = end[0] - start[0];
  const lost = start[1] - end[1];
  drain = span >= 20 && isNum(lost) && lost > 0 ? lost / span : null;
}

async function check() {
  const seq = ++checkSeq;
  legs = [];
  render();
  if (!items.length) return;
  if (auth !== "valid") {  // the station reads plans for its operator only
    showAck($("#plan-ack"), "Check", "sign in with the operator token to check the legs against the scene", "bad");
    return;
  }
  const { status, data } = await api("POST", "/api/plan/check", planBody());
  if (seq !== checkSeq) return;
  legs = status === 200 && data && Array.isArray(data.legs) ? data.legs : [];
  if (status !== 200) showAck($("#plan-ack"), "Check", detailText(data) || `error ${status}`, "bad");
  renderLegs();
  renderSummary();
  publish();
}

function render() {
  renderItems();
  renderSummary();
  updateControls();
  publish();
  $("#map2d").dataset.plan = String(items.length);
}

function changed() {
  render();
  check();
}

// ---- editing --------------------------------------------------------------------------------------------
function newItem(action, x, y) {
  const alt = Number($("#plan-alt").value);
  return { action, x, y, alt: isNum(alt) && alt >= 0 ? alt : 5, speed: null, hold: 0 };
}

/** A click on the 2D map, or on the ground in the 3D view, while editing: a waypoint there. */
function addWaypoint({ x, y }) {
  if (!editing || !isNum(x) || !isNum(y)) return;
  const v = vehicle();
  if (!items.length && (!v || v.type === "copter")) {
    const [hx, hy] = home();
    items.push(newItem("takeoff", hx, hy));
  }
  items.push(newItem("waypoint", x, y));
  selected = items.length - 1;
  changed();
}
on(EVENTS.mapClick, addWaypoint);
on(EVENTS.target, addWaypoint);

on(EVENTS.planMove, ({ index, x, y, done }) => {
  const p = items[index];
  if (!p || !isNum(x) || !isNum(y)) return;
  p.x = x;
  p.y = y;
  selected = index;
  if (done) changed();
  else { legs[index] = null; legs[index + 1] = null; publish(); }
});

$("#plan-items").addEventListener("change", (event) => {
  const row = event.target.closest("tr");
  const p = row && items[Number(row.dataset.index)];
  if (!p) return;
  const field = event.target.dataset.field;
  if (field === "action") {
    p.action = event.target.value;
  } else {
    const value = event.target.value === "" ? null : Number(event.target.value);
    const ok = value === null ? field === "speed" : isNum(value) && value >= Number(event.target.min || 0)
      && value <= Number(event.target.max || Infinity) && (field !== "speed" || value > 0);
    if (!ok) {
      showAck($("#plan-ack"), `Item ${Number(row.dataset.index) + 1}`,
        `${field} must be between ${event.target.min} and ${event.target.max}`, "bad");
      event.target.value = isNum(p[field]) ? String(p[field]) : "";
      return;
    }
    p[field] = field === "hold" ? value || 0 : value;
  }
  changed();
});

$("#plan-items").addEventListener("click", (event) => {
  const row = event.target.closest("tr");
  if (!row) return;
  const index = Number(row.dataset.index);
  if (event.target.closest(".plan-delete")) {
    items.splice(index, 1);
    selected = null;
    changed();
    return;
  }
  if (selected !== index) {
    selected = index;
    for (const r of $("#plan-items").children) r.classList.toggle("selected", Number(r.dataset.index) === index);
    publish();
  }
});

$("#plan-edit").addEventListener("click", () => {
  editing = !editing;
  $("#plan-edit").setAttribute("aria-pressed", String(editing));
  publish();
});
$("#plan-clear").addEventListener("click", () => { items = []; selected = null; changed(); });
$("#plan-cruise").addEventListener("change", renderSummary);

// ---- the vehicle: upload, download, fly -----------------------------------------------------------------
function updateControls() {
  const v = vehicle();
  const reason = commandBlocker(auth, mode);
  const none = v ? "" : "Select a vehicle first";
  const empty = items.length ? "" : "The plan has no items";
  setEnabled($("#plan-upload"), reason || none || empty, "Upload the plan to the selected vehicle");
  setEnabled($("#plan-download"), reason || none, "Download the selected vehicle's mission into the plan");
  // a mission this station uploaded or downloaded (its waypoints), or one MISSION_CURRENT counts past home
  const holds = v && ((Array.isArray(v.waypoints) && v.waypoints.length) || (v.mission && isNum(v.mission.total)
    && v.mission.total > 1));
  const noMission = holds ? "" : "The vehicle holds no mission: upload the plan (or download its own) first";
  setEnabled($("#plan-fly"), reason || none || noMission,
    "Arm if needed, AUTO, and start the vehicle's uploaded mission");
  showHint($("#plan .command-hint"), reason);
  setText($("#plan-vehicle"), v ? `· vehicle ${v.sysid} ${v.type || ""}` : "");
}

/** Poll the transfer's progress into the bar until `done` resolves. */
async function withProgress(sysid, running) {
  const bar = $("#plan-progress");
  bar.hidden = false;
  bar.value = 0;
  let finished = false;
  const poll = async () => {
    while (!finished) {
      const p = await getJson(`/api/vehicles/${sysid}/mission/progress`);
      if (p && isNum(p.total) && p.total > 0) { bar.max = p.total; bar.value = p.done; }
      await new Promise((resolve) => setTimeout(resolve, 100));
    }
  };
  poll();
  try {
    return await running;
  } finally {
    finished = true;
    const p = await getJson(`/api/vehicles/${sysid}/mission/progress`);
    if (p && isNum(p.total)) { bar.max = p.total; bar.value = p.done; }
  }
}

$("#plan-upload").addEventListener("click", async () => {
  const v = vehicle();
  if (!v || !items.length) return;
  const ack = $("#plan-ack");
  const label = `Upload to vehicle ${v.sysid}`;
  showAck(ack, label, "sending…", "pending");
  const text = await apiText("POST", "/api/plan/export?format=wpl", JSON.stringify(planBody()),
    "application/json");
  if (text.status !== 200) { showAck(ack, label, errorOf(text), "bad"); return; }
  const sent = await withProgress(v.sysid, apiText("PUT", `/api/vehicles/${v.sysid}/mission`, text.text));
  const data = parse(sent.text);
  if (sent.status === 200 && data) {
    showAck(ack, label, `${data.result} (MISSION_ACK, ${data.items} items with home)`,
      data.result === "accepted" ? "ok" : "bad");
  } else {
    showAck(ack, label, errorOf(sent), "bad");
  }
});

$("#plan-download").addEventListener("click", async () => {
  const v = vehicle();
  if (!v) return;
  const ack = $("#plan-ack");
  const label = `Download from vehicle ${v.sysid}`;
  showAck(ack, label, "receiving…", "pending");
  const got = await withProgress(v.sysid, apiText("GET", `/api/vehicles/${v.sysid}/mission`));
  if (got.status !== 200) { showAck(ack, label, errorOf(got), "bad"); return; }
  if (await load(got.text, label)) showAck(ack, label, `${items.length} items`, "ok");
});

$("#plan-fly").addEventListener("click", () => {
  const v = vehicle();
  if (!v) return;
  postWithAck($("#plan-ack"), `Fly (AUTO) vehicle ${v.sysid}`, `/api/vehicles/${v.sysid}/commands`,
    { action: "auto" });
});

// ---- files ----------------------------------------------------------------------------------------------
function parse(text) {
  try { return JSON.parse(text); } catch { return null; }
}

function errorOf({ status, text }) {
  if (status === 0) return text;
  const data = parse(text);
  return data && data.detail ? detailText(data) : `error ${status}`;
}

/** Read a mission file's text through the station into the plan; false (and the reason shown) if refused. */
async function load(text, label) {
  const got = await apiText("POST", "/api/plan/import", text);
  const data = got.status === 200 ? parse(got.text) : null;
  if (!data || !Array.isArray(data.items)) {
    showAck($("#plan-ack"), label, errorOf(got), "bad");
    return false;
  }
  items = data.items.map((p) => ({ action: p.action, x: p.x, y: p.y, alt: p.alt, speed: p.speed, hold: p.hold }));
  selected = null;
  changed();
  return true;
}

$("#plan-file").addEventListener("change", async (event) => {
  const file = event.target.files && event.target.files[0];
  event.target.value = "";
  if (!file) return;
  const label = `Import ${file.name}`;
  if (file.size > 8 << 20) { showAck($("#plan-ack"), label, "larger than 8 MB: not a mission file", "bad"); return; }
  if (await load(await file.text(), label)) showAck($("#plan-ack"), label, `${items.length} items`, "ok");
});

async function exportAs(format) {
  const v = vehicle();
  const kind = v && v.type === "rover" ? "rover" : "copter";
  const got = await apiText("POST", `/api/plan/export?format=${format}&vehicle=${kind}`,
    JSON.stringify(planBody()), "application/json");
  if (got.status !== 200) { showAck($("#plan-ack"), "Export", errorOf(got), "bad"); return; }
  const link = el("a");
  link.href = URL.createObjectURL(new Blob([got.text], { type: "text/plain" }));
  link.download = format === "plan" ? "mission.plan" : "mission.waypoints";
  document.body.append(link);
  link.click();
  link.remove();
  setTimeout(() => URL.revokeObjectURL(link.href), 10_000);
  showAck($("#plan-ack"), "Export", `${link.download} (${items.length} items)`, "ok");
}
$("#plan-export-wpl").addEventListener("click", () => exportAs("wpl"));
$("#plan-export-plan").addEventListener("click", () => exportAs("plan"));

// ---- the rest of the page -------------------------------------------------------------------------------
on(EVENTS.auth, (detail) => {
  const was = auth;
  auth = detail.auth;
  updateControls();
  if (auth === "valid" && was !== "valid" && items.length) check();
});
on(EVENTS.selected, () => { measureDrain(); changed(); });  // another vehicle: another home, other legs
let lastCurrent = null;
on(EVENTS.status, (msg) => {
  mode = msg.mode;
  vehicles = Array.isArray(msg.vehicles) ? msg.vehicles : [];
  updateControls();
  const current = currentIndex();
  if (current !== lastCurrent) {  // the item being flown, on the map and in the table
    lastCurrent = current;
    for (const r of $("#plan-items").children) r.classList.toggle("current", Number(r.dataset.index) === current);
    publish();
  }
});
setInterval(() => { measureDrain().then(renderSummary); }, 10_000);
window.addEventListener("DOMContentLoaded", () => { render(); measureDrain().then(renderSummary); });
