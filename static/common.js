// What the page's scripts share: the REST helper, the DOM and number helpers, the battery's text, and the
// events by which the scripts talk. No framework, no build step: every script is an ES module served from
// /static/, and every string from the server goes into the page with textContent, never innerHTML (messages,
// recording names and error details come from vehicles and files we do not control).
//
// The scripts, one per panel:
//   app.js         the status socket, the 3D view's frame, the side panel's toggle
//   auth.js        the Operator section: the token, signing in and out, the session cookie for watching
//   vehicles.js    a card per vehicle with its commands
//   replay.js      the LIVE/REPLAY banner and the replay's controls
//   recordings.js  the recordings list and its Replay buttons
//   target.js      "Go here": the target picked in the 3D view or on the 2D map, until the vehicle sent reaches it
//   health.js      the station's own health, at the top of the panel
//   operator.js    the fleet list (the selection), the selected vehicle's instruments, the warning banner
//   map2d.js       the 2D map;  plots.js  the selected vehicle's telemetry against time
//   view3d.js      this page's own 3D view: camera modes, keys, layers
//   plan.js        the plan view: a mission clicked on the 2D map, checked, uploaded, imported, exported, flown
//   rti.js         the radio tomography panel: links per second, coverage, the peaks
//
// The contract: every event is a CustomEvent on `window`, its payload in `event.detail`. Each script adds its
// listeners when it runs and starts talking on DOMContentLoaded, so no script misses another's first word.
//   station-status   app.js, each status frame (4/s): {type: "vehicles", mode: "live"|"replay", time,
//                    vehicles: [...] (sorted by sysid), replay: {...}|null, recordings?: [...]}
//                    -> vehicles, replay, recordings, target, operator, map2d, plots, view3d
//   station-socket   app.js, each time the socket opens: {viewerId, send(request)}, send talks to the station
//                    about this page's 3D view -> view3d, auth (a reconnect re-checks the token)
//   station-view     app.js, the station's answer about this page's 3D view: {type: "view"|"view-error", ...}
//                    -> view3d
//   station-target   app.js, a ground point clicked in this page's 3D view, or map2d.js, a plain click on the 2D
//                    map (not a drag, not measuring, the plan not editing): {x, y} (m) -> target, plan, map2d,
//                    view3d (which has the station mark it in this page's 3D view)
//   station-target-done  target.js, the Go here target is no more: the vehicle sent there reached it
//                    {reason} -> map2d, view3d (both take their marks away)
//   station-watching app.js, whether this station lets the page watch without a token: {refused: bool}, once
//                    at start and again whenever it changes -> auth (its hint; it checks the token after the
//                    first), recordings (reloads)
//   station-session  auth.js, a token opened a session (the cookie that lets this browser watch): {renewed}, true
//                    when a new token (a new address's #token) replaced the old one -> app, view3d
//   station-auth     auth.js, the sign-in state changed: {auth: "none"|"checking"|"valid"|"viewer"|"invalid"|
//                    "unverified"} (only "valid" commands) -> vehicles, target, replay, recordings
//   station-token-rejected  common.js (describeResult), a command answered 401: {} -> auth
//   vehicle-selected operator.js, the operator picked a vehicle: {sysid}; also window.selectedVehicle
//                    -> map2d, plots, view3d
//   map2d-click      map2d.js, a click on the 2D map (not a drag, not measuring) while the plan edits: {x, y} (m)
//                    -> plan
//   plan-changed     plan.js, the plan to draw: {editing, items: [{action, x, y, alt, ...}], home: [x, y]|null,
//                    legs: [{blocked}], selected: index|null, current: index|null} -> map2d
//   plan-move        map2d.js, a plan item dragged on the map: {index, x, y, done} (done when let go) -> plan
//   rti-frame        rti.js, the station's latest radio tomography frame: {frame: /api/rti's frame|null,
//                    picture: {bounds, img (a loaded Image), scale: {max, unit, colours}}|null, targets: [[x, y]]}
//                    -> map2d (the image layer, its colour bar, peaks, links, targets)

export const EVENTS = Object.freeze({
  status: "station-status",
  socket: "station-socket",
  view: "station-view",
  target: "station-target",
  targetDone: "station-target-done",
  watching: "station-watching",
  session: "station-session",
  auth: "station-auth",
  tokenRejected: "station-token-rejected",
  selected: "vehicle-selected",
  mapClick: "map2d-click",
  plan: "plan-changed",
  planMove: "plan-move",
  rti: "rti-frame",
});

/** Send one of EVENTS with its payload. */
export function emit(name, detail = {}) {
  window.dispatchEvent(new CustomEvent(name, { detail }));
}

/** Listen to one of EVENTS; the handler gets the payload. */
export function on(name, handler) {
  window.addEventListener(name, (event) => handler(event.detail ?? {}));
}

export const SIGN_IN_HINT = "Sign in with the operator token to command vehicles";
export const REPLAY_SIGN_IN_HINT = "Sign in with the operator token to control replay";
export const REPLAY_HINT = "Commands are disabled in replay";
const REQUEST_TIMEOUT_MS = 30000;  // the server answers 504 itself when a vehicle stays silent

// ---------------------------------------------------------------------------------------------
// DOM and numbers

export const $ = (sel, root = document) => root.querySelector(sel);

export function isNum(v) {
  return typeof v === "number" && Number.isFinite(v);
}

/** A number with fixed decimals, "–" when missing; never "-0.0". */
export function fmt(v, digits = 1) {
  if (!isNum(v)) return "–";
  const s = v.toFixed(digits);
  return Number(s) === 0 ? (0).toFixed(digits) : s;
}

/** An image from a URL (a PNG data URL from the station), or null when it does not load. */
export function loadImage(url) {
  return new Promise((resolve) => {
    const img = new Image();
    img.onload = () => resolve(img);
    img.onerror = () => resolve(null);
    img.src = url;
  });
}

/** Map bounds [west, south, east, north] (m) that enclose some area. */
export function validBounds(b) {
  return Array.isArray(b) && b.length === 4 && b.every(isNum) && b[2] > b[0] && b[3] > b[1];
}

/** Build a plain element with text; never parses HTML. */
export function el(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text !== undefined) node.textContent = text;
  return node;
}

/** Only touch the DOM when the text changes (4 updates/s; keeps selection and screen readers calm). */
export function setText(node, text) {
  if (node.textContent !== text) node.textContent = text;
}

/** A battery (the stream's {voltage, remaining, current}) as every panel says it: "12.3 V, 87 %". MAVLink's
 * -1 (or the stream's null) for "remaining unknown" leaves the percentage out. groundstation/export.py's
 * battery_text says the same (a test compares the two). */
export function batteryText(b) {
  if (!b) return "–";
  const parts = [];
  if (isNum(b.voltage)) parts.push(`${fmt(b.voltage)} V`);
  if (isNum(b.remaining) && b.remaining >= 0) parts.push(`${Math.round(b.remaining)} %`);
  return parts.length ? parts.join(", ") : "–";
}

/** A vehicle as the cards and the "Go here" selector name it. */
export function vehicleName(v) {
  return `Vehicle ${v.sysid} · ${v.type || "other"}`;
}

// ---------------------------------------------------------------------------------------------
// Controls

export function setEnabled(button, reason, help) {
  button.disabled = Boolean(reason);
  button.title = reason || help || "";
  if (reason) button.setAttribute("aria-description", reason);
  else button.removeAttribute("aria-description");
}

export function showHint(hintEl, reason) {
  hintEl.hidden = !reason;
  setText(hintEl, reason);
}

/** Why vehicle commands are not possible right now, or "" when they are. */
export function commandBlocker(auth, mode) {
  if (mode === "replay") return REPLAY_HINT;
  if (auth !== "valid") return SIGN_IN_HINT;
  return "";
}

/** Why the replay (shared by every viewer) cannot be controlled from here, or "". */
export function replayBlocker(auth) {
  return auth === "valid" ? "" : REPLAY_SIGN_IN_HINT;
}

// ---------------------------------------------------------------------------------------------
// REST

let token = "";

/** The operator's (or a viewer's) token that api() sends; auth.js sets it. */
export function setToken(value) {
  token = value;
}

/**
 * Call the API with the token. Resolves to {status, data} (data: parsed JSON or null);
 * status 0 means the server could not be reached.
 */
export async function api(method, path, body) {
  const headers = {};
  if (token) headers.Authorization = `Bearer ${token}`;
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

/** Send text (a mission file) and read the answer as text: {status, text} (status 0: unreachable). */
export async function apiText(method, path, text, type = "text/plain") {
  const headers = { "Content-Type": type };
  if (token) headers.Authorization = `Bearer ${token}`;
  const abort = new AbortController();
  const timer = setTimeout(() => abort.abort(), REQUEST_TIMEOUT_MS);
  try {
    const res = await fetch(path, { method, headers, signal: abort.signal, body: text });
    return { status: res.status, text: await res.text() };
  } catch (err) {
    return { status: 0, text: err.name === "AbortError" ? "no answer from server" : "server unreachable" };
  } finally {
    clearTimeout(timer);
  }
}

/** GET a JSON document: its data, or null when the answer is not a success. */
export async function getJson(path) {
  const { status, data } = await api("GET", path);
  return status >= 200 && status < 300 ? data : null;
}

/** FastAPI's `detail` is a string or a list of {loc, msg}; make it one readable line. */
export function detailText(data) {
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

const RESULT_CLASS = {
  accepted: "ok",
  "in progress": "warn",
  "temporarily rejected": "warn",
};

/** Turn a command response into {text, cls} for an .ack element. */
function describeResult({ status, data, error }) {
  if (status === 0) return { text: error, cls: "bad" };
  if (status === 401) {
    // The token changes every time the server starts: auth.js drops it so the page asks again.
    emit(EVENTS.tokenRejected);
    return { text: "not signed in", cls: "bad" };
  }
  if (status === 404) return { text: "no such vehicle", cls: "bad" };
  if (status === 422) return { text: detailText(data), cls: "bad" };
  if (status === 504) return { text: "timeout", cls: "bad" };
  if (status >= 200 && status < 300) {
    const result = data && typeof data.result === "string" ? data.result : "done";
    const cls = RESULT_CLASS[result] || (result === "done" ? "ok" : "bad");
    const why = data && (data.reason || data.note);  // a refusal's reason, or what an accepted command did
    return { text: why ? `${result}: ${why}` : result, cls };
  }
  const extra = data && data.detail ? `: ${detailText(data)}` : "";
  return { text: `error ${status}${extra}`, cls: "bad" };
}

const REPLY_FADES_MS = 20000;  // a reply this old is shown faded: it no longer says what the vehicle is doing

export function showAck(ackEl, label, text, cls) {
  ackEl.className = `ack ${cls}`;
  const time = new Date().toLocaleTimeString([], { hour12: false });
  ackEl.textContent = cls === "pending" ? `${label}: ${text}` : `${label}: ${text} · ${time}`;
  clearTimeout(ackEl._fade);
  if (cls !== "pending") ackEl._fade = setTimeout(() => ackEl.classList.add("stale"), REPLY_FADES_MS);
}

/**
 * POST a request and show its progress and result in `ackEl`. A sequence number per ack area
 * makes sure a slow early answer never overwrites the result of a later click.
 */
export async function postWithAck(ackEl, label, path, body) {
  const seq = (Number(ackEl.dataset.seq) || 0) + 1;
  ackEl.dataset.seq = String(seq);
  showAck(ackEl, label, "sending…", "pending");
  const response = await api("POST", path, body);
  if (Number(ackEl.dataset.seq) !== seq) return response;
  const { text, cls } = describeResult(response);
  showAck(ackEl, label, text, cls);
  return response;
}
