// scanstation operator page: the status socket (/ws) and the events it feeds every panel (see common.js for the
// contract), whether this station lets the page watch, the viser 3D view's frame, and the side panel's toggle.
// Each panel has its own script; this one only connects them to the station.

import { $, EVENTS, api, emit, isNum, on, setText } from "./common.js";

/** A random, unguessable id for this page load: its 3D view and its stream present it, so the server
 * routes click-to-go targets to this viewer and no other. */
function makeViewerId() {
  const bytes = new Uint8Array(16);
  crypto.getRandomValues(bytes);  // (randomUUID exists only in secure contexts; a LAN address over http is not)
  return Array.from(bytes, (b) => b.toString(16).padStart(2, "0")).join("");
}

const viewerId = makeViewerId();
let socket = null;
let retryDelay = 500;
let retryTimer = null;
let watchRefused = null;  // watching needs a token this page has not given yet (null: not asked yet)

// ---------------------------------------------------------------------------------------------
// Watching and the 3D view's frame

function setupView() {
  // viser's client connects to the socket of its page's own path: /viz/v/ID/ -> /viz/v/ID
  $("#view").src = `/viz/v/${viewerId}/`;
}

/** Does this station need a token to watch? Said with "station-watching" the first time and on a change. */
async function checkWatching() {
  const { status } = await api("GET", "/api/health");
  const refused = status === 401;
  if (refused && watchRefused === false) $("#view").removeAttribute("src");
  if (refused !== watchRefused) {
    watchRefused = refused;
    emit(EVENTS.watching, { refused });
  }
  return refused;
}

// A token opened a session: when watching was refused before, the view and the stream start again now; when a
// new token replaced the old one (a new address in this tab), the stream (and view3d.js its view).
on(EVENTS.session, ({ renewed }) => {
  if (watchRefused) {
    watchRefused = false;
    emit(EVENTS.watching, { refused: false });
    setupView();
    reconnectNow();
  } else if (renewed) {
    reconnectNow();
  }
});

// ---------------------------------------------------------------------------------------------
// The status socket

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
    const vehicles = (Array.isArray(msg.vehicles) ? msg.vehicles : [])
      .filter((v) => v && v.sysid != null)
      .sort((a, b) => a.sysid - b.sysid);
    emit(EVENTS.status, { ...msg, mode: msg.mode === "replay" ? "replay" : "live", replay: msg.replay || null,
                          vehicles });
  } else if (msg.type === "view" || msg.type === "view-error") {
    emit(EVENTS.view, msg);  // view3d.js's answers
  } else if (msg.type === "target" && isNum(msg.x) && isNum(msg.y)) {
    emit(EVENTS.target, { x: msg.x, y: msg.y });
  }
}

function connect() {
  const proto = location.protocol === "https:" ? "wss:" : "ws:";
  socket = new WebSocket(`${proto}//${location.host}/ws?viewer=${encodeURIComponent(viewerId)}`);
  let opened = false;
  socket.addEventListener("open", () => {
    opened = true;
    retryDelay = 500;
    setConnection("connected", "connected");
    // view3d.js talks to the station about this page's own 3D view over this socket; auth.js re-checks the token
    const open = socket;
    emit(EVENTS.socket, {
      viewerId, send: (request) => open.readyState === WebSocket.OPEN && open.send(JSON.stringify(request)) });
  });
  socket.addEventListener("message", onMessage);
  const mine = socket;
  socket.addEventListener("close", async () => {
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

window.addEventListener("DOMContentLoaded", async () => {
  setupPanel();
  setConnection("connecting", "connecting…");
  if (!await checkWatching()) setupView();  // else once a token opens a session
  connect();
});
