// A card per vehicle: its mode, the onboard agent's state, position, speed, heading, battery, link, mission,
// map, clock and last messages, with its commands (Abort, Return home, GUIDED, Resume, Pause, Continue, Take
// control, Arm, Land, Take off, Kill). Cards follow the status frames ("station-status"); commands need the
// operator's token and live mode. Kill is pressed and held (KILL_HOLD_MS): let go sooner and the card says it
// was not sent. A reply fades once REPLY_FADES_MS old, and the last message line once STATUS_FADES_S old.

import {
  $, EVENTS, batteryText, commandBlocker, el, fmt, isNum, on, postWithAck, setEnabled, setText, showAck, showHint,
  vehicleName,
} from "./common.js";

const KILL_HOLD_MS = 1500;
const MAX_MESSAGES = 5;
const STATUS_FADES_S = 30;  // s after which the last message line is shown faded
const BATTERY_LOW = 20;  // % left at or below which a battery is shown as low, until the vehicle tells its own level
const FAILSAFE_UNREAD = "Failsafe levels not read yet: the station asks the autopilot for its BATT_LOW_* and "
  + `BATT_CRT_* parameters when it hears it (an autopilot that never answers has none shown). Marked low at ${
    BATTERY_LOW} % meanwhile.`;

// One failsafe level of battery.failsafe (the vehicle's own BATT_* parameters): "low 20 % (1000 mAh) → warn".
// A voltage or capacity of 0 is that check off, as ArduPilot has it; "?" is a parameter not answered yet.
function levelText(name, level) {
  const at = [];
  if (isNum(level.volt) && level.volt > 0) at.push(`${fmt(level.volt)} V`);
  if (isNum(level.mah) && level.mah > 0) {
    at.push(isNum(level.percent) ? `${Math.round(level.percent)} % (${Math.round(level.mah)} mAh)`
      : `${Math.round(level.mah)} mAh`);
  }
  const when = at.length ? at.join(" or ") : level.volt === 0 && level.mah === 0 ? "off" : "?";
  const action = level.action == null ? "?" : level.action === "None" ? "warn" : level.action;
  return `${name} ${when} → ${action}`;
}

function failsafeText(failsafe) {
  if (!failsafe) return "not read yet";
  return `${levelText("low", failsafe.low)}; ${levelText("critical", failsafe.critical)}`;
}

// The card's Failsafe row, made once after the battery's (the page's card template has none): the dd.
function failsafeRow(battery) {
  const next = battery.nextElementSibling;
  if (next && next.classList.contains("failsafe-label")) return next.nextElementSibling;
  const line = el("dd", "battery-failsafe");
  battery.after(el("dt", "failsafe-label", "Failsafe"), line);
  return line;
}

function failsafeHelp(failsafe) {
  if (!failsafe) return FAILSAFE_UNREAD;
  const capacity = isNum(failsafe.capacity_mah) ? `, capacity ${Math.round(failsafe.capacity_mah)} mAh` : "";
  return `The vehicle's own battery failsafe (its BATT_LOW_*, BATT_CRT_* and BATT_FS_*_ACT parameters${capacity}): `
    + `${failsafeText(failsafe)}. "warn" is a warning only; "?" not answered yet.`;
}

function minutes(seconds) {
  return seconds >= 90 ? `${Math.round(seconds / 60)} min` : `${Math.round(seconds)} s`;
}

// What each vehicle button sends. `body(card)` builds the JSON for POST .../commands.
const ACTIONS = {
  abort: { label: "Abort", help: "Stop the mission and hold position",
           body: () => ({ action: "abort" }) },
  rtl: { label: "Return home", help: "Return to launch",
         body: () => ({ action: "rtl" }) },
  guided: { label: "GUIDED", help: "Switch to GUIDED mode",
            body: () => ({ action: "set_mode", mode: "GUIDED" }) },
  resume: { label: "AUTO / Resume", help: "Resume the mission",
            body: () => ({ action: "resume" }) },
  pause: { label: "Pause", help: "Hold where it is; an onboard agent pauses its mission until Continue",
           body: () => ({ action: "pause" }) },
  continue: { label: "Continue", help: "Resume the paused mission (or hand control back to the agent)",
              body: () => ({ action: "continue" }) },
  take_control: { label: "Take control", help: "The agent holds the vehicle and commands nothing until you hand back",
                  body: () => ({ action: "take_control" }) },
  arm: { label: "Arm", help: "Arm the motors",
         body: () => ({ action: "arm" }) },
  takeoff: { label: "Take off", help: "Take off to the altitude on the right",
             body: (card) => ({ action: "takeoff", altitude: takeoffAltitude(card) }) },
  land: { label: "Land", help: "Land where the vehicle is",
          body: () => ({ action: "land" }) },
  kill: { label: "Kill", help: "Stop the motors at once (a flying copter falls). Press and hold 1.5 s to send.",
          body: () => ({ action: "kill", confirm: true }) },
};

const cards = new Map();  // sysid -> card element
let auth = "none";
let mode = "live";

function clockTime(unixSeconds) {
  if (!isNum(unixSeconds)) return "";
  return new Date(unixSeconds * 1000).toLocaleTimeString([], { hour12: false });
}

function updateCardControls(card) {
  const reason = commandBlocker(auth, mode);
  for (const button of card.querySelectorAll("button[data-action]")) {
    const action = button.dataset.action;
    if (reason && action === "kill") resetKill(button);
    setEnabled(button, reason, ACTIONS[action].help);
  }
  card.querySelector(".takeoff-altitude").disabled = Boolean(reason);
  showHint(card.querySelector(".command-hint"), reason);
}

function updateControls() {
  for (const card of cards.values()) updateCardControls(card);
}

function takeoffAltitude(card) {
  return Number(card.querySelector(".takeoff-altitude").value);
}

function resetKill(button) {
  clearTimeout(button._killTimer);
  button._killTimer = null;
  button._killStart = null;
  button.classList.remove("confirming");
  setText(button, ACTIONS.kill.label);
}

/** Kill is irreversible in the air: it is sent only once held for KILL_HOLD_MS (pointer, Space or Enter). */
function startKillHold(card, button) {
  if (button.disabled || button._killTimer) return;
  button._killStart = performance.now();
  button.classList.add("confirming");
  button.style.setProperty("--hold-ms", `${KILL_HOLD_MS}ms`);
  button.textContent = "Keep holding to kill…";
  button._killTimer = setTimeout(() => {
    resetKill(button);
    sendCommand(card, "kill");
  }, KILL_HOLD_MS);
}

/** Let go before the hold is complete: nothing is sent, and the card says so. */
function endKillHold(card, button) {
  if (!button._killTimer) return;
  const held = (performance.now() - button._killStart) / 1000;
  resetKill(button);
  showAck(card.querySelector(".ack"), ACTIONS.kill.label,
    `not sent: released after ${held.toFixed(1)} s; hold ${KILL_HOLD_MS / 1000} s to kill`, "warn");
}

function sendCommand(card, action) {
  const sysid = card.dataset.sysid;
  const ack = card.querySelector(".ack");
  const { label, body } = ACTIONS[action];
  const payload = body(card);
  if (action === "takeoff" && !(payload.altitude > 0)) {
    showAck(ack, label, "enter a take-off altitude above 0 m", "bad");
    return;
  }
  postWithAck(ack, label, `/api/vehicles/${encodeURIComponent(sysid)}/commands`, payload);
}

function createCard(sysid) {
  const card = $("#vehicle-template").content.firstElementChild.cloneNode(true);
  card.dataset.sysid = String(sysid);
  const commands = card.querySelector(".commands");
  commands.setAttribute("aria-label", `Commands for vehicle ${sysid}`);
  commands.addEventListener("click", (event) => {
    const button = event.target.closest("button[data-action]");
    if (!button || button.disabled || button.dataset.action === "kill") return;
    sendCommand(card, button.dataset.action);
  });
  const kill = card.querySelector('[data-action="kill"]');
  kill.addEventListener("pointerdown", (event) => {
    if (kill.hasPointerCapture && event.pointerId !== undefined) {
      try { kill.setPointerCapture(event.pointerId); } catch { /* a synthetic event has no pointer to capture */ }
    }
    startKillHold(card, kill);
  });
  // let go, or the button loses the pointer or the focus: the hold ends, and nothing is sent
  for (const name of ["pointerup", "pointercancel", "lostpointercapture", "blur"]) {
    kill.addEventListener(name, () => endKillHold(card, kill));
  }
  kill.addEventListener("keydown", (event) => {
    if ((event.key === " " || event.key === "Enter") && !event.repeat) {
      event.preventDefault();
      startKillHold(card, kill);
    }
  });
  kill.addEventListener("keyup", (event) => {
    if (event.key === " " || event.key === "Enter") endKillHold(card, kill);
  });
  // Escape backs out of a kill being held.
  card.addEventListener("keydown", (event) => {
    if (event.key === "Escape") endKillHold(card, kill);
  });
  updateCardControls(card);
  return card;
}

function positionText(p) {
  if (!p) return "–";
  const part = (name, v) => (isNum(v) ? `${name} ${fmt(v)} m` : `${name} –`);
  return `${part("x", p.x)}, ${part("y", p.y)}, ${part("alt", p.z)}`;
}

function headingText(h) {
  if (!isNum(h)) return "–";
  return `${((Math.round(h) % 360) + 360) % 360}°`;
}

/** The autopilot's mission: the item it flies to, and what is left of it (distance, and time at its speed). */
function progressText(m) {
  if (!m || !isNum(m.total) || m.total <= 0) return "no mission";
  const item = `item ${isNum(m.current) ? m.current : "–"} / ${m.total}`;
  const rest = m.left && isNum(m.left.m) ? m.left : null;
  if (!rest) return item;
  const time = isNum(rest.s) && isNum(rest.speed) ? `, about ${minutes(rest.s)} at ${fmt(rest.speed)} m/s` : "";
  return `${item} · ${Math.round(rest.m)} m left${time}`;
}

function mapText(m) {
  if (!m || !isNum(m.occupied)) return "–";
  const source = m.source ? ` (${m.source})` : "";
  return `${m.occupied} occupied cells${source}`;
}

/** The last MAX_MESSAGES STATUSTEXTs, newest first (the server lists them oldest first). */
function recentMessages(messages) {
  if (!Array.isArray(messages)) return [];
  const list = messages.slice().reverse();
  if (list.every((m) => m && isNum(m.time))) list.sort((a, b) => b.time - a.time);
  return list.slice(0, MAX_MESSAGES);
}

function renderMessages(ul, messages) {
  const list = recentMessages(messages);
  // Cheap change check so the list is not rebuilt 4 times a second.
  const key = JSON.stringify(list.map((m) => [m && m.time, m && m.severity, m && m.text]));
  if (ul.dataset.key === key) return;
  ul.dataset.key = key;
  ul.replaceChildren();
  if (!list.length) {
    ul.append(el("li", "none", "no messages"));
    return;
  }
  for (const m of list) {
    const severe = m && isNum(m.severity) && m.severity <= 3;  // EMERGENCY..ERROR
    const li = el("li", severe ? "severe" : "");
    li.append(el("time", "msg-time", clockTime(m && m.time)), el("span", "msg-text", String((m && m.text) ?? "")));
    ul.append(li);
  }
}

/** How far the agent's mission is: its waypoints done, and the time left of its time budget. */
function progressOf(p) {
  if (!p) return "";
  const parts = [];
  if (isNum(p.total) && p.total > 0) parts.push(`waypoint ${Math.min(p.done + 1, p.total)} of ${p.total}`);
  if (isNum(p.time_left)) parts.push(`${minutes(Math.max(0, p.time_left))} left of its time budget`);
  return parts.length ? ` · ${parts.join(", ")}` : "";
}

/** The onboard agent's own state beside the autopilot's mode: a mission running, paused (and why), ended. */
function renderAgent(card, agent) {
  const badge = card.querySelector(".agent-state");
  const line = card.querySelector(".agent");
  if (!agent || typeof agent !== "object") {
    badge.hidden = true;
    setText(line, "no onboard agent heard");
    return;
  }
  const state = String(agent.state ?? "");
  const reason = agent.reason ? String(agent.reason) : "";
  badge.hidden = false;
  setText(badge, state ? state.toUpperCase() : "–");
  badge.className = `agent-state ${state}`;
  badge.title = reason ? `onboard mission ${state}: ${reason}` : `onboard mission ${state}`;
  const where = agent.companion ? "companion" : "onboard";
  setText(line, `${agent.mission ?? "?"} ${state}${reason ? ` (${reason})` : ""} · ${agent.phase ?? "?"} · ${where}`
    + progressOf(agent.progress));
  // Who commands: the card says so while the operator holds the agent, and Continue names what it does
  const control = card.querySelector(".control-banner");
  const held = agent.operator === "control" ? "You have control: the agent commands nothing until you hand back."
    : agent.operator === "pause" ? "Paused by you: the vehicle holds here until Continue." : "";
  control.hidden = !held;
  setText(control, held);
  setText(card.querySelector('[data-action="continue"]'), agent.operator === "control" ? "Hand back" : "Continue");
}

function renderCard(card, v) {
  setText(card.querySelector(".vehicle-title"), vehicleName(v));
  setText(card.querySelector(".mode"), v.mode ? String(v.mode) : "–");
  renderAgent(card, v.agent);
  const armed = card.querySelector(".armed");
  setText(armed, v.armed == null ? "–" : v.armed ? "ARMED" : "disarmed");
  armed.classList.toggle("is-armed", v.armed === true);

  setText(card.querySelector(".position"), positionText(v.position));
  setText(card.querySelector(".speed"), isNum(v.speed) ? `${fmt(v.speed)} m/s` : "–");
  setText(card.querySelector(".heading"), headingText(v.heading));
  const battery = card.querySelector(".battery");
  const left = v.battery && isNum(v.battery.flight_left_s) ? ` · about ${minutes(v.battery.flight_left_s)} of flight left`
    : "";
  setText(battery, `${batteryText(v.battery)}${left}`);
  const failsafe = v.battery ? v.battery.failsafe : null;
  const failsafeLine = failsafeRow(battery);
  failsafeLine.hidden = failsafeLine.previousElementSibling.hidden = !v.battery;
  setText(failsafeLine, failsafeText(failsafe));
  battery.title = `${v.battery && isNum(v.battery.current) ? `current ${fmt(v.battery.current)} A. ` : ""}${
    left ? "Flight left: at the rate it drained over the last two minutes. " : ""}${failsafeHelp(failsafe)}`;
  failsafeLine.title = failsafeHelp(failsafe);
  // the card marks the battery low where the vehicle warns (its own low level once read), before a failsafe acts
  const lowAt = failsafe && isNum(failsafe.low.percent) ? failsafe.low.percent : BATTERY_LOW;
  battery.classList.toggle("low", !!v.battery && isNum(v.battery.remaining) && v.battery.remaining >= 0
    && v.battery.remaining <= lowAt);

  const link = v.link || {};
  const lost = link.state === "lost";
  const age = isNum(link.heartbeat_age) ? `${fmt(link.heartbeat_age)} s` : "–";
  const signed = link.signed ? " · signed" : "";
  setText(card.querySelector(".link"), lost ? "LINK LOST" : link.state ? `link ${link.state} · ${age}${signed}` : "–");
  card.classList.toggle("lost", lost);
  const banner = card.querySelector(".lost-banner");
  banner.hidden = !lost;
  setText(banner, lost ? `LINK LOST — no heartbeat for ${age}` : "");
  card.querySelector(".link").title = link.signed ? "its messages carry a valid MAVLink 2 signature" : "";

  // Another ground station commanding the same vehicle: the operator must know orders may not be theirs.
  const other = v.other_gcs;
  const otherBanner = card.querySelector(".other-gcs-banner");
  otherBanner.hidden = !other;
  setText(otherBanner, other ? `Another ground station (system ${other.sysid}) is commanding this vehicle: ` +
    `${other.last}, ${fmt(other.age)} s ago` : "");

  setText(card.querySelector(".progress-item"), progressText(v.mission));
  const status = card.querySelector(".progress-status");
  setText(status, v.status ? String(v.status) : "");
  status.classList.toggle("stale", isNum(v.status_age) && v.status_age > STATUS_FADES_S);
  const crash = card.querySelector(".crash-banner");
  crash.hidden = !v.crash;
  setText(crash, v.crash ? `CRASH: ${v.crash.text} (${fmt(v.crash.age)} s ago)` : "");
  setText(card.querySelector(".map"), mapText(v.map));
  const nearMisses = card.querySelector(".near-misses");
  setText(nearMisses, isNum(v.near_misses) && v.near_misses > 0 ? `${v.near_misses} (see the event log)` : "none");
  nearMisses.classList.toggle("warning", isNum(v.near_misses) && v.near_misses > 0);
  setText(card.querySelector(".sim-time"), isNum(v.time_boot_s) ? `t = ${fmt(v.time_boot_s)} s` : "–");
  renderMessages(card.querySelector(".messages"), v.messages);
}

function renderVehicles(vehicles) {
  const container = $("#vehicles");
  const seen = new Set();
  let previous = null;
  for (const v of vehicles) {
    const key = String(v.sysid);
    seen.add(key);
    let card = cards.get(key);
    if (!card) {
      card = createCard(v.sysid);
      cards.set(key, card);
    }
    renderCard(card, v);
    // into sorted order, moved only when out of place: a moved card loses the keyboard's focus (a Kill held)
    const next = previous ? previous.nextElementSibling : container.firstElementChild;
    if (next !== card) container.insertBefore(card, next);
    previous = card;
  }
  for (const [key, card] of cards) {
    if (!seen.has(key)) {
      card.remove();
      cards.delete(key);
    }
  }
  $("#no-vehicles").hidden = vehicles.length > 0;
}

on(EVENTS.auth, (detail) => {
  auth = detail.auth;
  updateControls();
});
/** The demo's own vehicles starting: said while the first start compiles the simulator, and how long it took. */
function renderStarting(starting, count) {
  const empty = $("#no-vehicles");
  const note = $("#start-note");
  const waiting = starting && !isNum(starting.took) && !count;
  setText(empty, waiting ? `Starting the vehicles: ${fmt(starting.since)} s so far. The first start after an install `
    + "compiles the simulator's loops (about 15 s); later starts take a second or two."
    : "No vehicles yet — waiting for MAVLink heartbeats");
  note.hidden = !(starting && isNum(starting.took));
  setText(note, note.hidden ? "" : `The vehicles started in ${fmt(starting.took)} s.`);
}

on(EVENTS.status, (msg) => {
  mode = msg.mode;
  renderVehicles(msg.vehicles);
  renderStarting(msg.starting, msg.vehicles.length);
  updateControls();
});
window.addEventListener("DOMContentLoaded", () => renderVehicles([]));
