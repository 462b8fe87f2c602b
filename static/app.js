// scanstation operator page: live status over /ws, commands over the REST API, the viser 3D
// view in an iframe. No framework and no build step. Every string that comes from the server
// is put into the page with textContent (never innerHTML), because STATUSTEXTs, recording
// names and error details come from vehicles and files we do not control.

const TOKEN_KEY = "scanstation.token";
const SIGN_IN_HINT = "Sign in with the operator token to command vehicles";
const REPLAY_SIGN_IN_HINT = "Sign in with the operator token to control replay";
const REPLAY_HINT = "Commands are disabled in replay";
const TOKEN_EXPIRED = "The server no longer accepts this token (it changes when the server restarts). Sign in again.";
const KILL_CONFIRM_MS = 5000;
const REQUEST_TIMEOUT_MS = 30000;  // the server answers 504 itself when a vehicle stays silent
const SEEK_THROTTLE_MS = 250;
const MAX_MESSAGES = 5;

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
  arm: { label: "Arm", help: "Arm the motors",
         body: () => ({ action: "arm" }) },
  takeoff: { label: "Take off", help: "Take off to the altitude on the right",
             body: (card) => ({ action: "takeoff", altitude: takeoffAltitude(card) }) },
  land: { label: "Land", help: "Land where the vehicle is",
          body: () => ({ action: "land" }) },
  kill: { label: "Kill", help: "Stop the motors at once (a flying copter falls). Click twice to confirm.",
          body: () => ({ action: "kill", confirm: true }) },
};

const RESULT_CLASS = {
  accepted: "ok",
  "in progress": "warn",
  "temporarily rejected": "warn",
};

// ---------------------------------------------------------------------------------------------
// Page state

const state = {
  token: "",
  auth: "none",          // none | checking | valid | viewer | invalid | unverified
  watchRefused: false,   // watching needs a token this page has not given yet
  mode: "live",          // live | replay, as the server last said
  vehicles: [],          // last vehicle list from the stream (kept while reconnecting)
  replay: null,          // last replay status from the stream
  target: null,          // {x, y} picked in this viewer's 3D view
  connected: false,
};

const $ = (sel, root = document) => root.querySelector(sel);
const cards = new Map();  // sysid -> card element

// ---------------------------------------------------------------------------------------------
// Small helpers

/** A random, unguessable id for this page load: its 3D view and its stream present it, so the server
 * routes click-to-go targets to this viewer and no other. */
function makeViewerId() {
  const bytes = new Uint8Array(16);
  crypto.getRandomValues(bytes);  // (randomUUID exists only in secure contexts; a LAN address over http is not)
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}

function isNum(v) {
  return typeof v === "number" && Number.isFinite(v);
}

/** A number with fixed decimals, "–" when missing; never "-0.0". */
function fmt(v, digits = 1) {
  if (!isNum(v)) return "–";
  const s = v.toFixed(digits);
  return Number(s) === 0 ? (0).toFixed(digits) : s;
}

/** Only touch the DOM when the text changes (4 updates/s; keeps selection and screen readers calm). */
function setText(el, text) {
  if (el.textContent !== text) el.textContent = text;
}

function clockTime(unixSeconds) {
  if (!isNum(unixSeconds)) return "";
  return new Date(unixSeconds * 1000).toLocaleTimeString([], { hour12: false });
}

function readStoredToken() {
  try { return localStorage.getItem(TOKEN_KEY) || ""; } catch { return ""; }
}

function storeToken(token) {
  try {
    if (token) localStorage.setItem(TOKEN_KEY, token);
    else localStorage.removeItem(TOKEN_KEY);
  } catch { /* storage disabled: the token lives for this page only */ }
}

/** Build a plain element with text; never parses HTML. */
function el(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined) node.textContent = text;
  return node;
}

/** A function that calls fn at most every `ms`, always delivering the last value (trailing call). */
function throttle(fn, ms) {
  let last = 0;
  let timer = null;
  let pending;
  return (value) => {
    pending = value;
    const wait = last + ms - performance.now();
    if (wait <= 0 && !timer) {
      last = performance.now();
      fn(pending);
    } else if (!timer) {
      timer = setTimeout(() => {
        timer = null;
        last = performance.now();
        fn(pending);
      }, Math.max(wait, 0));
    }
  };
}

// ---------------------------------------------------------------------------------------------
// REST

/**
 * Call the API with the operator token. Resolves to {status, data} (data: parsed JSON or null);
 * status 0 means the server could not be reached.
 */
async function api(method, path, body) {
  const headers = {};
  if (state.token) headers.Authorization = `Bearer ${state.token}`;
  if (body !== undefined) headers["Content-Type"] = "application/json";
  const abort = new AbortController();
  const timer = setTimeout(() => abort.abort(), REQUEST_TIMEOUT_MS);
  try {
    const res = await fetch(path, {
      method, headers, signal: abort.signal,
      body: body === undefined ? undefined : JSON.stringify(body),
    });
    let data = null;
    try { data = await res.json(); } catch { /* empty or non-JSON body */ }
    return { status: res.status, data };
  } catch (err) {
    return { status: 0, data: null, error: err.name === "AbortError" ? "no answer from server" : "server unreachable" };
  } finally {
    clearTimeout(timer);
  }
}

/** FastAPI's `detail` is a string or a list of {loc, msg}; make it one readable line. */
function detailText(data) {
  const detail = data && data.detail;
  if (typeof detail === "string") return detail;
  if (Array.isArray(detail)) {
    return detail.map((d) => {
      const where = Array.isArray(d.loc) ? d.loc.filter((p) => p !== "body").join(".") : "";
      return where ? `${where}: ${d.msg}` : String(d.msg ?? d);
    }).join("; ");
  }
  return "invalid request";
}

/** Turn a command response into {text, cls} for an .ack element. */
function describeResult({ status, data, error }) {
  if (status === 0) return { text: error, cls: "bad" };
  if (status === 401) {
    // The token changes every time the server starts: drop it so the page asks again.
    markTokenRejected();
    return { text: "not signed in", cls: "bad" };
  }
  if (status === 404) return { text: "no such vehicle", cls: "bad" };
  if (status === 422) return { text: detailText(data), cls: "bad" };
  if (status === 504) return { text: "timeout", cls: "bad" };
  if (status >= 200 && status < 300) {
    const result = data && typeof data.result === "string" ? data.result : "done";
    return { text: result, cls: RESULT_CLASS[result] || (result === "done" ? "ok" : "bad") };
  }
  const extra = data && data.detail ? `: ${detailText(data)}` : "";
  return { text: `error ${status}${extra}`, cls: "bad" };
}

function showAck(ackEl, label, text, cls) {
  ackEl.className = `ack ${cls}`;
  const time = new Date().toLocaleTimeString([], { hour12: false });
  ackEl.textContent = cls === "pending" ? `${label}: ${text}` : `${label}: ${text} · ${time}`;
}

/**
 * POST a request and show its progress and result in `ackEl`. A sequence number per ack area
 * makes sure a slow early answer never overwrites the result of a later click.
 */
async function postWithAck(ackEl, label, path, body) {
  const seq = (Number(ackEl.dataset.seq) || 0) + 1;
  ackEl.dataset.seq = String(seq);
  showAck(ackEl, label, "sending…", "pending");
  const response = await api("POST", path, body);
  if (Number(ackEl.dataset.seq) !== seq) return response;
  const { text, cls } = describeResult(response);
  showAck(ackEl, label, text, cls);
  return response;
}

// ---------------------------------------------------------------------------------------------
// Auth

/**
 * Ask the server whether `token` is the operator token. `quiet` re-checks a token already
 * accepted (after a reconnect) without disabling the buttons meanwhile.
 */
async function checkToken(token, quiet = false) {
  state.token = token;
  if (!quiet) setAuth("checking");
  const { status } = await api("GET", "/api/auth");
  if (state.token !== token) return;  // signed out or replaced meanwhile
  if (status === 200) {
    storeToken(token);
    await openSession();
    if (state.auth !== "valid") setAuth("valid");
  } else if ((status === 401 || status === 403) && await openSession() && state.token === token) {
    storeToken(token);  // not the operator's, but a viewer's: it may watch
    if (state.auth !== "viewer") setAuth("viewer");
  } else if (status === 401 || status === 403) {
    storeToken("");
    state.token = "";
    setAuth("invalid", quiet ? TOKEN_EXPIRED : undefined);
  } else if (!quiet) {
    // Server down or restarting: keep the token and try again when /ws comes back.
    storeToken(token);
    setAuth("unverified");
  }
}

/**
 * Trade the token for the cookie that lets this browser watch (the 3D view and the stream cannot send
 * a header). Only a station served beyond loopback asks for it; elsewhere it is harmless. When watching
 * was refused before, the view and the stream start again now.
 */
async function openSession() {
  const { status } = await api("POST", "/api/session");
  if (status !== 204) return false;
  if (state.watchRefused) {
    state.watchRefused = false;
    $("#watch-hint").hidden = true;
    setupView();
    reconnectNow();
    loadRecordings();
  }
  return true;
}

/** The stream was refused before it opened: does this station need a token to watch? */
async function checkWatching() {
  const { status } = await api("GET", "/api/health");
  const refused = status === 401;
  if (refused && !state.watchRefused) $("#view").removeAttribute("src");
  state.watchRefused = refused;
  $("#watch-hint").hidden = !refused;
  return refused;
}

function markTokenRejected() {
  if (state.auth === "valid") {
    storeToken("");
    state.token = "";
    setAuth("invalid", TOKEN_EXPIRED);
  }
}

function setAuth(auth, message) {
  state.auth = auth;
  const status = $("#auth-status");
  const messages = {
    none: "Not signed in",
    checking: "Checking token…",
    valid: "Signed in",
    viewer: "Watching (the viewer token cannot command)",
    invalid: "Wrong token",
    unverified: "Cannot check the token: server unreachable. Retrying when connected.",
  };
  status.textContent = message || messages[auth];
  status.className = `auth-status ${auth}`;
  const signedIn = auth === "valid" || auth === "viewer";
  $("#auth-form").hidden = signedIn;
  $("#sign-out").hidden = auth === "none" || auth === "invalid";
  updateControls();
}

function signOut() {
  storeToken("");
  state.token = "";
  $("#token").value = "";
  setAuth("none");
}

/** A link like http://host/#token=abc signs in directly; the token leaves the address bar at once. */
function takeTokenFromHash() {
  if (!location.hash) return "";
  const params = new URLSearchParams(location.hash.slice(1));
  const token = params.get("token");
  if (!token) return "";
  params.delete("token");
  const rest = params.toString();
  history.replaceState(null, "", location.pathname + location.search + (rest ? `#${rest}` : ""));
  return token;
}

function setupAuth() {
  $("#auth-form").addEventListener("submit", (event) => {
    event.preventDefault();
    const token = $("#token").value.trim();
    if (!token) {
      setAuth("none", "Enter the operator token printed by the server");
      return;
    }
    $("#token").value = "";
    checkToken(token);
  });
  $("#sign-out").addEventListener("click", signOut);

  const token = takeTokenFromHash() || readStoredToken();
  if (token) checkToken(token);
  else setAuth("none");
}

// ---------------------------------------------------------------------------------------------
// Enabling and disabling controls

/** Why commands are not possible right now, or "" when they are. */
function commandBlocker() {
  if (state.mode === "replay") return REPLAY_HINT;
  if (state.auth !== "valid") return SIGN_IN_HINT;
  return "";
}

function setEnabled(button, reason, help) {
  button.disabled = Boolean(reason);
  button.title = reason || help || "";
  if (reason) button.setAttribute("aria-description", reason);
  else button.removeAttribute("aria-description");
}

function showHint(hintEl, reason) {
  hintEl.hidden = !reason;
  setText(hintEl, reason);
}

function updateCardControls(card) {
  const reason = commandBlocker();
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

  // Go here: a command too, and needs a target and a vehicle.
  const reason = commandBlocker();
  const goHere = $("#go-here");
  const missing = !state.target ? "Click the ground in the 3D view first"
    : !state.vehicles.length ? "No vehicle to send" : "";
  setEnabled(goHere, reason || missing, "Send the selected vehicle to the target");
  showHint($("#target .command-hint"), reason);

  // Replay controls and the Replay buttons need the token (the replay is shared by all viewers).
  const replayReason = state.auth === "valid" ? "" : REPLAY_SIGN_IN_HINT;
  for (const id of ["#replay-play", "#replay-back", "#replay-step", "#replay-stop"]) {
    setEnabled($(id), replayReason, $(id).dataset.help);
  }
  $("#replay-speed").disabled = Boolean(replayReason);
  $("#replay-time").disabled = Boolean(replayReason);
  showHint($("#replay .replay-hint"), replayReason);
  for (const button of document.querySelectorAll("#recordings-list .replay-button")) {
    setEnabled(button, replayReason, "Replay this recording in the 3D view");
  }
  showHint($("#recordings .recordings-hint"),
    replayReason && document.querySelector("#recordings-list .replay-button") ? replayReason : "");
}

// ---------------------------------------------------------------------------------------------
// Vehicle cards

function takeoffAltitude(card) {
  return Number(card.querySelector(".takeoff-altitude").value);
}

function resetKill(button) {
  clearTimeout(button._killTimer);
  button._killTimer = null;
  button.classList.remove("confirming");
  setText(button, ACTIONS.kill.label);
}

/** Kill is irreversible in the air: the first click only arms a 5 s confirmation. */
function onKillClick(card, button) {
  if (!button._killTimer) {
    button.classList.add("confirming");
    button.textContent = "Confirm kill?";
    button._killTimer = setTimeout(() => resetKill(button), KILL_CONFIRM_MS);
    return;
  }
  resetKill(button);
  sendCommand(card, "kill");
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
    if (!button || button.disabled) return;
    if (button.dataset.action === "kill") onKillClick(card, button);
    else sendCommand(card, button.dataset.action);
  });
  // Escape backs out of a pending kill confirmation.
  card.addEventListener("keydown", (event) => {
    if (event.key === "Escape") resetKill(card.querySelector('[data-action="kill"]'));
  });
  updateCardControls(card);
  return card;
}

function vehicleName(v) {
  return `Vehicle ${v.sysid} · ${v.type || "other"}`;
}

function positionText(p) {
  if (!p) return "–";
  const part = (name, v) => (isNum(v) ? `${name} ${fmt(v)} m` : `${name} –`);
  return `${part("x", p.x)}, ${part("y", p.y)}, ${part("alt", p.z)}`;
}

const BATTERY_LOW = 20;  // % left at or below which a vehicle's battery is shown as low

function batteryText(b) {
  if (!b) return "–";
  const parts = [];
  if (isNum(b.voltage)) parts.push(`${fmt(b.voltage)} V`);
  // MAVLink uses -1 for "remaining unknown".
  if (isNum(b.remaining) && b.remaining >= 0) parts.push(`${Math.round(b.remaining)} %`);
  return parts.length ? parts.join(", ") : "–";
}

function headingText(h) {
  if (!isNum(h)) return "–";
  return `${((Math.round(h) % 360) + 360) % 360}°`;
}

function progressText(m) {
  if (!m || !isNum(m.total) || m.total <= 0) return "no mission";
  return `item ${isNum(m.current) ? m.current : "–"} / ${m.total}`;
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
  setText(line, `${agent.mission ?? "?"} ${state}${reason ? ` (${reason})` : ""} · ${agent.phase ?? "?"} · ${where}`);
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
  setText(battery, batteryText(v.battery));
  battery.title = v.battery && isNum(v.battery.current) ? `current ${fmt(v.battery.current)} A` : "";
  // ArduPilot warns at its low level, and our simulator at 20 %: the card says so before the failsafe acts
  battery.classList.toggle("low", !!v.battery && isNum(v.battery.remaining) && v.battery.remaining >= 0
    && v.battery.remaining <= BATTERY_LOW);

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
  setText(card.querySelector(".progress-status"), v.status ? String(v.status) : "");
  setText(card.querySelector(".map"), mapText(v.map));
  setText(card.querySelector(".sim-time"), isNum(v.time_boot_s) ? `t = ${fmt(v.time_boot_s)} s` : "–");
  renderMessages(card.querySelector(".messages"), v.messages);
}

function renderVehicles(vehicles) {
  const container = $("#vehicles");
  const seen = new Set();
  for (const v of vehicles) {
    const key = String(v.sysid);
    seen.add(key);
    let card = cards.get(key);
    if (!card) {
      card = createCard(v.sysid);
      cards.set(key, card);
    }
    renderCard(card, v);
    container.append(card);  // append moves existing cards into sorted order (no-op if in place)
  }
  for (const [key, card] of cards) {
    if (!seen.has(key)) {
      card.remove();
      cards.delete(key);
    }
  }
  $("#no-vehicles").hidden = vehicles.length > 0;
}

/** Keep the "Go here" vehicle selector in step with the vehicle list, keeping the user's choice. */
function renderTargetVehicles(vehicles) {
  const select = $("#target-vehicle");
  const key = vehicles.map((v) => `${v.sysid}:${v.type}`).join(",");
  if (select.dataset.key === key) return;
  select.dataset.key = key;
  const previous = select.value;
  select.replaceChildren(...vehicles.map((v) => {
    const option = el("option", "", vehicleName(v));
    option.value = String(v.sysid);
    return option;
  }));
  if (vehicles.some((v) => String(v.sysid) === previous)) select.value = previous;
  select.disabled = vehicles.length === 0;
}

// ---------------------------------------------------------------------------------------------
// Mode, replay and target

function renderMode(mode, replay) {
  const banner = $("#mode-banner");
  const isReplay = mode === "replay";
  setText(banner, isReplay ? "REPLAY" : "LIVE");
  banner.className = `mode-banner ${isReplay ? "replay" : "live"}`;
  document.body.classList.toggle("replaying", isReplay);
  const panel = $("#replay");
  const starting = isReplay && panel.hidden;
  panel.hidden = !isReplay;
  // The Replay button sits at the bottom of the panel; bring the new controls into view.
  if (starting) panel.scrollIntoView({ block: "nearest" });
  if (isReplay && replay) renderReplay(replay);
}

let sliderHeld = false;     // the user is dragging the time slider: do not move it under them
let sliderQuietUntil = 0;   // after a seek, ignore stream times until the server has caught up

function renderReplay(r) {
  setText($("#replay-name"), r.name ? String(r.name) : "");
  const playing = Boolean(r.playing);
  const play = $("#replay-play");
  setText(play, playing ? "Pause" : "Play");
  play.dataset.playing = String(playing);
  play.setAttribute("aria-pressed", String(playing));

  const speed = $("#replay-speed");
  if (document.activeElement !== speed && isNum(r.speed)) {
    const match = Array.from(speed.options).find((o) => Number(o.value) === r.speed);
    if (match) speed.value = match.value;
  }

  const slider = $("#replay-time");
  const duration = isNum(r.duration) ? r.duration : 0;
  if (slider.max !== String(duration)) slider.max = String(duration);
  if (!sliderHeld && performance.now() > sliderQuietUntil && isNum(r.time)) {
    slider.value = String(r.time);
    renderClock(r.time, duration);
  }
}

function renderClock(time, duration) {
  setText($("#replay-clock"), `${fmt(time)} / ${fmt(duration)} s`);
}

function renderTarget(target) {
  const coords = $("#target-coords");
  coords.textContent = target ? `x ${fmt(target.x)} m, y ${fmt(target.y)} m` : "Click the ground in the 3D view to pick a target";
  coords.classList.toggle("has-target", Boolean(target));
  updateControls();
}

/** Render one "vehicles" message from the stream. */
function render(msg) {
  const vehicles = (Array.isArray(msg.vehicles) ? msg.vehicles : [])
    .filter((v) => v && v.sysid != null)
    .sort((a, b) => a.sysid - b.sysid);
  const modeChanged = msg.mode !== state.mode;
  state.vehicles = vehicles;
  state.mode = msg.mode === "replay" ? "replay" : "live";
  state.replay = msg.replay || null;

  renderMode(state.mode, state.replay);
  renderVehicles(vehicles);
  renderTargetVehicles(vehicles);
  if (modeChanged) loadRecordings();
  else if (Array.isArray(msg.recordings)) renderRecordings(msg.recordings);
  updateControls();
  // The operator's view (operator.js, map2d.js, plots.js) draws from the same frames.
  window.dispatchEvent(new CustomEvent("station-status", { detail: msg }));
}

// ---------------------------------------------------------------------------------------------
// The station's own health: a link down, a stalled link thread, a recording that fails, vehicles turned
// away, a vehicle far from the scene. Said at the top of the panel, since every number below may be stale,
// incomplete or drawn in the wrong place because of it.

const HEALTH_PERIOD_MS = 5000;
const ELSEWHERE_SHOWN_MS = 60000;  // how long messages dropped as from elsewhere stay said after the last one
const elsewhere = new Map();  // sysid -> { messages: dropped so far, at: when that count last grew (page clock) }

function healthProblems(health) {
  const problems = [];
  for (const far of (health && health.far_from_scene) || []) {
    problems.push(`vehicle ${far.sysid} is ${far.km.toLocaleString("en")} km from the scene: ` +
                  "is the station's datum where it flies? (--datum, or the scene's)");
  }
  const link = health && health.link;
  if (!link) return problems;
  for (const port of link.links || []) {
    if (!port.up) problems.push(`MAVLink ${port.url} is down${port.error ? `: ${port.error}` : ""}`);
  }
  if (link.thread !== "ok") problems.push("the MAVLink thread has stalled: nothing new is received");
  if (link.recording_error) problems.push(`recording failed: ${link.recording_error}`);
  const held = link.vehicles || {};
  if (held.refused) problems.push(`${held.refused} new vehicles turned away: ${held.held} held, the most allowed`);
  for (const refused of (link.signing && link.signing.refused) || []) {
    problems.push(`system ${refused.sysid}: ${refused.messages} messages dropped, not signed with the key`);
  }
  for (const dropped of link.from_elsewhere || []) {
    const seen = elsewhere.get(dropped.sysid);
    if (!seen || dropped.messages > seen.messages) elsewhere.set(dropped.sysid, { messages: dropped.messages, at: Date.now() });
    if (Date.now() - elsewhere.get(dropped.sysid).at < ELSEWHERE_SHOWN_MS) {
      problems.push(`vehicle ${dropped.sysid}: ${dropped.messages} messages in its autopilot's name dropped, from ` +
                    "elsewhere than its heartbeat (a second link to it, or someone sending as it)");
    }
  }
  return problems;
}

async function checkHealth() {
  const { status, data } = await api("GET", "/api/health");
  const banner = $("#health-banner");
  const problems = status === 200 ? healthProblems(data) : [];
  banner.hidden = problems.length === 0;
  banner.replaceChildren(...problems.map((text) => el("li", "", text)));
  banner.dataset.checked = String(status);  // when it last looked, and what the station answered
}

// ---------------------------------------------------------------------------------------------
// WebSocket

const viewerId = makeViewerId();
let socket = null;
let retryDelay = 500;
let everConnected = false;
let retryTimer = null;

/** Connect again at once (the page was just given what it lacked), not after the backoff. */
function reconnectNow() {
  retryDelay = 500;
  clearTimeout(retryTimer);
  if (socket && socket.readyState <= WebSocket.OPEN) socket.close();  // its close handler reconnects
  else connect();
}

function setConnection(kind, text) {
  $("#connection").className = `connection ${kind}`;
  setText($("#connection-text"), text);
  // Last known values stay on screen while reconnecting, but look stale.
  document.body.classList.toggle("stale", kind !== "connected");
}

function onMessage(event) {
  let msg;
  try { msg = JSON.parse(event.data); } catch { return; }
  if (!msg || typeof msg !== "object") return;
  if (msg.type === "vehicles") {
    render(msg);
    document.dispatchEvent(new CustomEvent("station-vehicles", { detail: state.vehicles }));
  } else if (msg.type === "view" || msg.type === "view-error") {
    document.dispatchEvent(new CustomEvent("station-view", { detail: msg }));  // view3d.js's answers
  } else if (msg.type === "target" && isNum(msg.x) && isNum(msg.y)) {
    state.target = { x: msg.x, y: msg.y };
    renderTarget(state.target);
  }
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${proto}//${location.host}/ws?viewer=${encodeURIComponent(viewerId)}`);
  let opened = false;
  socket.addEventListener("open", () => {
    opened = true;
    retryDelay = 500;
    state.connected = true;
    setConnection("connected", "connected");
    // After a drop the server may have restarted, and with it the token: check it again.
    if (state.token && state.auth === "unverified") checkToken(state.token);
    else if (everConnected && state.token && state.auth === "valid") checkToken(state.token, true);
    everConnected = true;
    // view3d.js talks to the station about this page's own 3D view over this socket
    const open = socket;
    document.dispatchEvent(new CustomEvent("station-socket", { detail: {
      viewerId, send: (request) => open.readyState === WebSocket.OPEN && open.send(JSON.stringify(request)) } }));
  });
  socket.addEventListener("message", onMessage);
  const mine = socket;
  socket.addEventListener("close", async () => {
    state.connected = false;
    const refused = !opened && await checkWatching();
    if (socket !== mine) return;  // reconnected meanwhile
    setConnection("reconnecting", refused ? "this station needs a token to watch: sign in"
      : "reconnecting… showing the last known state");
    // Exponential backoff with jitter, so many pages do not hammer a restarting server together.
    retryTimer = setTimeout(connect, retryDelay * (0.8 + Math.random() * 0.4));
    retryDelay = Math.min(retryDelay * 2, 10000);
  });
  // "error" is always followed by "close", which schedules the retry.
}

function setupView() {
  // viser's client connects to the socket of its page's own path: /viz/v/ID/ -> /viz/v/ID
  $("#view").src = `/viz/v/${viewerId}/`;
}

// ---------------------------------------------------------------------------------------------
// Target ("Go here")

function setupTarget() {
  $("#go-here").addEventListener("click", () => {
    const sysid = $("#target-vehicle").value;
    if (!state.target || !sysid) return;
    postWithAck($("#target .ack"), `Go here (vehicle ${sysid})`,
      `/api/vehicles/${encodeURIComponent(sysid)}/commands`,
      { action: "goto", x: state.target.x, y: state.target.y });
  });
}

// ---------------------------------------------------------------------------------------------
// Recordings and replay

function formatSize(bytes) {
  if (!isNum(bytes)) return "";
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 * 1024) return `${(bytes / 1024).toFixed(0)} kB`;
  return `${(bytes / 1024 / 1024).toFixed(1)} MB`;
}

function formatDuration(s) {
  if (!isNum(s)) return "";
  const total = Math.round(s);
  const h = Math.floor(total / 3600);
  const m = Math.floor((total % 3600) / 60);
  const sec = String(total % 60).padStart(2, "0");
  return h ? `${h}:${String(m).padStart(2, "0")}:${sec}` : `${m}:${sec}`;
}

function formatModified(modified) {
  // Unix seconds or an ISO string, whichever the server sends.
  const date = isNum(modified) ? new Date(modified * 1000) : typeof modified === "string" ? new Date(modified) : null;
  if (!date || Number.isNaN(date.getTime())) return "";
  return date.toLocaleString([], { dateStyle: "short", timeStyle: "short", hour12: false });
}

function recordingItem(rec) {
  const name = String(rec.name);
  const li = el("li", "recording");
  li.dataset.name = name;
  const info = el("div", "recording-info");
  info.append(el("span", "recording-name", name));
  info.append(el("span", "recording-meta", recordingMeta(rec)));

  const actions = el("div", "recording-actions");
  const replay = el("button", "btn btn-small replay-button", "Replay");
  replay.type = "button";
  replay.addEventListener("click", () => {
    postWithAck($("#recordings .ack"), `Replay ${name}`, "/api/replay", { name });
  });
  const download = el("a", "btn btn-small btn-link download", "Download");
  download.href = `/api/recordings/${encodeURIComponent(name)}`;
  download.setAttribute("download", name);
  actions.append(replay, download);
  li.append(info, actions);
  return li;
}

async function loadRecordings() {
  const list = $("#recordings-list");
  const { status, data, error } = await api("GET", "/api/recordings");
  if (status !== 200 || !Array.isArray(data)) {
    list.replaceChildren(el("li", "empty", `Could not load recordings (${status ? `HTTP ${status}` : error})`));
    delete list.dataset.key;
  } else {
    renderRecordings(data);
  }
  updateControls();
}

/** The recordings list, from GET /api/recordings or the stream (which lists them live: sizes and durations
 * grow, new sessions appear); rebuilt only when something changed. */
function renderRecordings(data) {
  const list = $("#recordings-list");
  const recordings = data.filter((r) => r && r.name != null);
  const key = JSON.stringify(recordings.map((r) => [r.name, r.size, r.duration_s, r.recording]));
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  if (!recordings.length) {
    list.replaceChildren(el("li", "empty", "No recordings yet"));
  } else {
    // Items are kept (only their sizes and durations change), so a click on Replay is never lost to a rebuild.
    const old = new Map(Array.from(list.querySelectorAll("li.recording"), (li) => [li.dataset.name, li]));
    list.replaceChildren(...recordings.map((rec) => {
      const li = old.get(String(rec.name)) || recordingItem(rec);
      setText(li.querySelector(".recording-meta"), recordingMeta(rec));
      li.classList.toggle("is-recording", Boolean(rec.recording));
      return li;
    }));
  }
  updateControls();
}

function recordingMeta(rec) {
  const meta = [formatDuration(rec.duration_s), formatSize(rec.size), formatModified(rec.modified)].filter(Boolean);
  return (rec.recording ? "recording · " : "") + meta.join(" · ");
}

function replayControl(label, body) {
  return postWithAck($("#replay .ack"), label, "/api/replay/control", body);
}

function setupReplay() {
  $("#replay-play").dataset.help = "Play or pause the replay";
  $("#replay-back").dataset.help = "Step back";
  $("#replay-step").dataset.help = "Step forward";
  $("#replay-stop").dataset.help = "Leave the replay and show live vehicles";

  $("#replay-play").addEventListener("click", () => {
    const play = $("#replay-play").dataset.playing !== "true";
    replayControl(play ? "Play" : "Pause", { play });
  });
  $("#replay-back").addEventListener("click", () => replayControl("Step back", { step: -1 }));
  $("#replay-step").addEventListener("click", () => replayControl("Step", { step: 1 }));
  $("#replay-speed").addEventListener("change", (event) => {
    replayControl("Speed", { speed: Number(event.target.value) });
  });

  // The slider seeks on "change" (release, or each arrow key), throttled so holding an arrow
  // key does not flood the server; while dragging, "input" only moves the clock text.
  const slider = $("#replay-time");
  const seek = throttle((seconds) => {
    sliderQuietUntil = performance.now() + 1000;
    replayControl("Seek", { seek: seconds });
  }, SEEK_THROTTLE_MS);
  slider.addEventListener("pointerdown", () => { sliderHeld = true; });
  window.addEventListener("pointerup", () => { sliderHeld = false; });
  window.addEventListener("pointercancel", () => { sliderHeld = false; });
  slider.addEventListener("input", () => {
    sliderQuietUntil = performance.now() + 1000;
    renderClock(Number(slider.value), Number(slider.max));
  });
  slider.addEventListener("change", () => seek(Number(slider.value)));

  $("#replay-stop").addEventListener("click", () => {
    postWithAck($("#replay .ack"), "Back to live", "/api/replay/stop", {});
  });

  $("#recordings-refresh").addEventListener("click", loadRecordings);
  $("#recordings").addEventListener("toggle", () => {
    if ($("#recordings").open) loadRecordings();
  });
}

// ---------------------------------------------------------------------------------------------
// Side panel (collapsible; an overlay drawer on narrow screens)

function setupPanel() {
  const toggle = $("#panel-toggle");
  const layout = $("#layout");
  const narrow = window.matchMedia("(max-width: 800px)");
  const apply = (open) => {
    layout.classList.toggle("panel-closed", !open);
    toggle.setAttribute("aria-expanded", String(open));
    toggle.title = open ? "Hide the side panel" : "Show the side panel";
  };
  // On a narrow screen the panel starts closed so the 3D view is usable.
  apply(!narrow.matches);
  narrow.addEventListener("change", (e) => apply(!e.matches));
  toggle.addEventListener("click", () => apply(layout.classList.contains("panel-closed")));
}

// ---------------------------------------------------------------------------------------------

async function main() {
  window.stationApi = api;  // for the operator's view's scripts (seeking from a plot needs the token)
  setupPanel();
  setupTarget();
  setupReplay();
  renderTarget(null);
  renderVehicles([]);
  setConnection("connecting", "connecting…");
  if (!await checkWatching()) setupView();  // else once a token opens a session
  setupAuth();
  connect();
  loadRecordings();
  checkHealth();
  setInterval(checkHealth, HEALTH_PERIOD_MS);
}

main();
