// scanstation: this page's own 3D view — camera mode, selected vehicle, layers, map opacity, keys and
// zoom towards the cursor. It asks the station over the page's /ws socket (app.js hands it over in a
// "station-socket" event); the station moves this viewer's camera alone, and answers with what it now
// does ("view") or why not ("view-error"). It also keeps the view connected: viser's client in a frame without
// focus does not reconnect by itself, so the view is reloaded when the station restarts (a new session in the
// status) or when its socket stays closed. No inline script, no eval: the page's policy forbids both.

import { $, EVENTS, isNum, on } from "./common.js";

const MODES = ["orbit", "follow", "onboard", "top"];
const KEYS = { 1: "orbit", 2: "follow", 3: "onboard", 4: "top" };
const ACTION_KEYS = { f: "fit", v: "vehicle" };
const ZOOM_EVERY_MS = 50;  // wheel steps are summed and sent at most this often
const DROPPED_VIEW_MS = 5000;  // a view that was connected and stays closed this long is loaded again
const SLOW_VIEW_MS = 60000;  // and one that never connected since it loaded (slow, or refused), this long

const view = {
  send: null,            // the socket's send, while it is open
  target: null,          // [x, y]: the Go here target this page holds, marked in its 3D view
  covered: "",           // the last box under the 2D map sent (as JSON), "" before any
  mode: "orbit",
  sysid: null,           // the selected vehicle (the page's selection, else the first vehicle)
  chosen: null,          // a vehicle the operator selected explicitly
  vehicles: [],
  zoom: null,            // {x, y, steps} not yet sent
  session: null,         // the station's session the view was loaded from
  loaded: false,         // the view's frame has loaded its page (its socket is about to open)
  connected: false,      // the station has said the view is connected since it last loaded
  downSince: null,       // since when (ms) the station has said the loaded view is not connected
};

function send(request) {
  if (view.send) view.send(request);
}

function layers() {
  const out = {};
  for (const box of document.querySelectorAll("#view3d input[data-layer]")) out[box.dataset.layer] = box.checked;
  return out;
}

function opacity() {
  return Number($("#map-opacity").value);
}

function showError(text) {
  const ack = $("#view3d .ack");
  ack.className = text ? "ack bad" : "ack";
  ack.textContent = text;
}

function renderMode(mode) {
  view.mode = mode;
  for (const button of document.querySelectorAll("#view3d [data-camera-mode]")) {
    button.setAttribute("aria-pressed", String(button.dataset.cameraMode === mode));
  }
}

function renderVehicle() {
  const text = view.sysid == null ? "no vehicle yet" : `camera on vehicle ${view.sysid}`;
  if ($("#view3d-vehicle").textContent !== text) $("#view3d-vehicle").textContent = text;
}

function setMode(mode) {
  if (!MODES.includes(mode)) return;
  renderMode(mode);
  send({ type: "camera", mode });
}

function act(action) {
  send({ type: "camera", action });
}

/** The vehicle the camera follows: the operator's choice while it exists, else the first one. */
function select() {
  const ids = view.vehicles.map((v) => v.sysid);
  const sysid = ids.includes(view.chosen) ? view.chosen : ids.length ? ids[0] : null;
  if (sysid !== view.sysid) {
    view.sysid = sysid;
    send({ type: "select", sysid });
  }
  renderVehicle();
}

const clamp = (v, low, high) => Math.min(high, Math.max(low, v));

function sendAll() {
  send({ type: "camera", mode: view.mode });
  send({ type: "select", sysid: view.sysid });
  send({ type: "layers", layers: layers(), opacity: opacity() });
  if (view.target) send({ type: "target", x: view.target[0], y: view.target[1] });
  view.covered = "";
  sendCovered();
}

/** The part of the 3D view the 2D map lies over, in the view's image coordinates (-1..1, y up), or null when
 * the map is swapped to the front (the 3D view is then the small picture above it): the orbit camera keeps a
 * vehicle out from under it. Sent when it changes. */
function sendCovered() {
  const frame = $("#view").getBoundingClientRect();
  const pane = $("#map2d-pane");
  let box = null;
  if (pane && frame.width > 0 && frame.height > 0 && !pane.closest(".map-first")) {
    const r = pane.getBoundingClientRect();
    const x0 = Math.max(r.left, frame.left), x1 = Math.min(r.right, frame.right);
    const y0 = Math.max(r.top, frame.top), y1 = Math.min(r.bottom, frame.bottom);
    if (x1 > x0 && y1 > y0) {
      const x = (px) => clamp(((px - frame.left) / frame.width) * 2 - 1, -1, 1);
      const y = (py) => clamp(1 - ((py - frame.top) / frame.height) * 2, -1, 1);
      box = [x(x0), y(y1), x(x1), y(y0)].map((v) => Math.round(v * 1000) / 1000);
    }
  }
  const key = JSON.stringify(box);
  if (key === view.covered) return;
  view.covered = key;
  send({ type: "covered", box });
}

// ---------------------------------------------------------------------------------------------
// Keys and the wheel, in the page and inside the 3D view's frame (same origin, so reachable from here)

function onKey(event) {
  if (event.ctrlKey || event.metaKey || event.altKey || event.repeat) return;
  const target = event.target;
  if (target && target.closest && target.closest("input, select, textarea, [contenteditable]")) return;
  const key = event.key.toLowerCase();
  if (KEYS[key]) setMode(KEYS[key]);
  else if (ACTION_KEYS[key]) act(ACTION_KEYS[key]);
  else return;
  event.preventDefault();
}

/** viser zooms towards its orbit centre and offers no zoom-to-cursor: the wheel over its canvas is taken
 * here and sent to the station, which moves the camera towards the point under the cursor. */
function onWheel(event) {
  const canvas = event.target && event.target.closest ? event.target.closest("canvas") : null;
  if (!canvas) return;  // viser's own panels scroll as usual
  event.preventDefault();
  event.stopImmediatePropagation();
  const rect = canvas.getBoundingClientRect();
  const x = ((event.clientX - rect.left) / rect.width) * 2 - 1;
  const y = 1 - ((event.clientY - rect.top) / rect.height) * 2;
  const lines = event.deltaMode === 1 ? event.deltaY * 33 : event.deltaMode === 2 ? event.deltaY * 400 : event.deltaY;
  const steps = -lines / 100;
  if (!Number.isFinite(x) || !Number.isFinite(y) || !Number.isFinite(steps)) return;
  if (!view.zoom) {
    view.zoom = { x, y, steps: 0 };
    setTimeout(flushZoom, ZOOM_EVERY_MS);
  }
  Object.assign(view.zoom, { x, y, steps: view.zoom.steps + steps });
}

function flushZoom() {
  const zoom = view.zoom;
  view.zoom = null;
  if (!zoom) return;
  send({ type: "zoom", x: clamp(zoom.x, -1, 1), y: clamp(zoom.y, -1, 1), steps: clamp(zoom.steps, -20, 20) });
}

/** Load the view's page again: a new viser client, which connects to the station now serving and draws its
 * scene from nothing (the old session's vehicles, labels and trails go with the old page). From its address
 * as the page set it (viser's client adds a ?websocket= query to its own, which the station refuses), in place
 * (no step added to the browser's history). */
function reloadFrame() {
  const frame = $("#view");
  const src = frame.getAttribute("src");
  if (!src) return;  // not watching
  view.loaded = false;
  view.downSince = null;
  try { frame.contentWindow.location.replace(src); } catch { frame.src = src; }
}

/** Each status frame says the station's session and whether this page's view is connected to it. */
function watchFrame(msg) {
  if (!$("#view").getAttribute("src") || typeof msg.session !== "string") return;  // not watching (yet)
  const restarted = view.session !== null && msg.session !== view.session;
  view.session = msg.session;
  if (restarted && msg.view !== true) {  // (connected already: viser's client, focused, came back by itself)
    reloadFrame();
  } else if (msg.view === true) {
    view.connected = true;
    view.downSince = null;
  } else if (msg.view === false && view.loaded) {
    const now = performance.now();
    if (view.downSince === null) view.downSince = now;
    else if (now - view.downSince > (view.connected ? DROPPED_VIEW_MS : SLOW_VIEW_MS)) reloadFrame();
  }
}

function hookFrame() {
  const frame = $("#view");
  frame.addEventListener("load", () => {  // loaded again (by this script or app.js): its wait starts now
    view.loaded = Boolean(frame.getAttribute("src"));
    view.connected = false;
    view.downSince = null;
  });
  const attach = () => {
    let win;
    try { win = frame.contentWindow; void win.document; } catch { return; }  // not ours (never, same origin)
    if (!win || win.__view3dHooked) return;
    win.__view3dHooked = true;
    win.addEventListener("keydown", onKey, true);
    win.addEventListener("wheel", onWheel, { capture: true, passive: false });
  };
  frame.addEventListener("load", attach);
  attach();
}

// ---------------------------------------------------------------------------------------------

function main() {
  for (const button of document.querySelectorAll("#view3d [data-camera-mode]")) {
    button.addEventListener("click", () => setMode(button.dataset.cameraMode));
  }
  for (const button of document.querySelectorAll("#view3d [data-camera-action]")) {
    button.addEventListener("click", () => act(button.dataset.cameraAction));
  }
  for (const box of document.querySelectorAll("#view3d input[data-layer]")) {
    box.addEventListener("change", () => send({ type: "layers", layers: { [box.dataset.layer]: box.checked } }));
  }
  $("#map-opacity").addEventListener("change", () => send({ type: "layers", opacity: opacity() }));
  window.addEventListener("keydown", onKey);
  const watchCover = new ResizeObserver(() => sendCovered());  // the map folded, swapped, the window resized
  watchCover.observe($("#view"));
  if ($("#map2d-pane")) watchCover.observe($("#map2d-pane"));

  on(EVENTS.socket, ({ send: socketSend }) => {
    view.send = typeof socketSend === "function" ? socketSend : null;
    sendAll();  // a new socket (the station may have restarted): tell it everything again
  });
  on(EVENTS.status, (msg) => {
    view.vehicles = msg.vehicles.filter((v) => Number.isInteger(v.sysid));
    select();
    watchFrame(msg);
  });
  // a new token replaced the old one (auth.js): the view connects again with it
  on(EVENTS.session, ({ renewed }) => {
    if (renewed && view.loaded) reloadFrame();
  });
  // the panel's selection (operator.js)
  on(EVENTS.selected, (detail) => {
    const sysid = Number(detail.sysid);
    if (!Number.isInteger(sysid)) return;
    view.chosen = sysid;
    select();
  });
  // the Go here target (target.js): marked in this page's 3D view until the vehicle sent there reaches it
  on(EVENTS.target, ({ x, y }) => {
    view.target = isNum(x) && isNum(y) ? [x, y] : null;
    send({ type: "target", x: view.target ? x : null, y: view.target ? y : null });
  });
  on(EVENTS.targetDone, () => {
    view.target = null;
    send({ type: "target", x: null, y: null });
  });
  on(EVENTS.view, (msg) => {
    if (msg.type === "view-error") {
      showError(`3D view: ${String(msg.detail ?? "refused")}`);
    } else {
      showError("");
      if (MODES.includes(msg.mode)) renderMode(msg.mode);
    }
  });
  hookFrame();
  renderVehicle();
}

main();
