// The Operator section: the token (typed, stored, or given in the address as #token=...), whether the station
// takes it as the operator's (commands) or a viewer's (watching only), and the session cookie that lets this
// browser watch a station served beyond loopback. Says the sign-in state with "station-auth" (common.js).

import { $, EVENTS, api, emit, on, setToken } from "./common.js";

const TOKEN_KEY = "scanstation.token";
const TOKEN_EXPIRED = "The server no longer accepts this token (it changes when the server restarts). Sign in again,"
  + " or open the new address it printed.";
const MESSAGES = {
  none: "Not signed in",
  checking: "Checking token…",
  valid: "Signed in",
  viewer: "Watching (the viewer token cannot command)",
  invalid: "Wrong token",
  unverified: "Cannot check the token: server unreachable. Retrying when connected.",
};

let token = "";
let auth = "none";
let opened = 0;  // how often the status socket has opened

function use(value) {
  token = value;
  setToken(value);
}

function readStoredToken() {
  try { return localStorage.getItem(TOKEN_KEY) || ""; } catch { return ""; }
}

function storeToken(value) {
  try {
    if (value) localStorage.setItem(TOKEN_KEY, value);
    else localStorage.removeItem(TOKEN_KEY);
  } catch { /* storage disabled: the token lives for this page only */ }
}

/**
 * Ask the server whether `candidate` is the operator token. `quiet` re-checks a token already
 * accepted (after a reconnect) without disabling the buttons meanwhile.
 */
async function checkToken(candidate, quiet = false, renewed = false) {
  use(candidate);
  if (!quiet) setAuth("checking");
  const { status } = await api("GET", "/api/auth");
  if (token !== candidate) return;  // signed out or replaced meanwhile
  if (status === 200) {
    storeToken(candidate);
    await openSession(renewed);
    if (auth !== "valid") setAuth("valid");
  } else if ((status === 401 || status === 403) && await openSession(renewed) && token === candidate) {
    storeToken(candidate);  // not the operator's, but a viewer's: it may watch
    if (auth !== "viewer") setAuth("viewer");
  } else if (status === 401 || status === 403) {
    storeToken("");
    use("");
    setAuth("invalid", quiet ? TOKEN_EXPIRED : undefined);
  } else if (!quiet) {
    // Server down or restarting: keep the token and try again when /ws comes back.
    storeToken(candidate);
    setAuth("unverified");
  }
}

/**
 * Trade the token for the cookie that lets this browser watch (the 3D view and the stream cannot send
 * a header). Only a station served beyond loopback asks for it; elsewhere it is harmless. ``renewed``: a new
 * token replaced the old one, so the stream and the view connect again with it.
 */
async function openSession(renewed = false) {
  const { status } = await api("POST", "/api/session");
  if (status !== 204) return false;
  emit(EVENTS.session, { renewed });
  return true;
}

function setAuth(next, message) {
  auth = next;
  const status = $("#auth-status");
  status.textContent = message || MESSAGES[next];
  status.className = `auth-status ${next}`;
  $("#auth-form").hidden = next === "valid" || next === "viewer";
  $("#sign-out").hidden = next === "none" || next === "invalid";
  emit(EVENTS.auth, { auth: next });
}

function signOut() {
  storeToken("");
  use("");
  $("#token").value = "";
  setAuth("none");
}

/** A link like http://host/#token=abc signs in directly; the token leaves the address bar at once. */
function takeTokenFromHash() {
  if (!location.hash) return "";
  const params = new URLSearchParams(location.hash.slice(1));
  const found = params.get("token");
  if (!found) return "";
  params.delete("token");
  const rest = params.toString();
  history.replaceState(null, "", location.pathname + location.search + (rest ? `#${rest}` : ""));
  return found;
}

$("#auth-form").addEventListener("submit", (event) => {
  event.preventDefault();
  const typed = $("#token").value.trim();
  if (!typed) {
    setAuth("none", "Enter the operator token printed by the server");
    return;
  }
  $("#token").value = "";
  checkToken(typed);
});
$("#sign-out").addEventListener("click", signOut);

// A new address pasted into this tab (a restarted station prints one; only its #token differs) changes only the
// hash, so the page is not loaded again: take its token in place of the old one.
window.addEventListener("hashchange", () => {
  const found = takeTokenFromHash();
  if (found) checkToken(found, false, true);
});

// The token changes every time the server starts: a command refused for it drops it, so the page asks again.
on(EVENTS.tokenRejected, () => {
  if (auth === "valid") {
    storeToken("");
    use("");
    setAuth("invalid", TOKEN_EXPIRED);
  }
});

// After a drop the server may have restarted, and with it the token: check it again.
on(EVENTS.socket, () => {
  opened += 1;
  if (token && auth === "unverified") checkToken(token);
  else if (opened > 1 && token && auth === "valid") checkToken(token, true);
});

// app.js says first whether this station lets the page watch without a token; the token is checked after it,
// so that a session it opens finds the view waiting for one.
let started = false;
on(EVENTS.watching, ({ refused }) => {
  $("#watch-hint").hidden = !refused;
  if (started) {
    // refused now with a token that was taken: the station restarted with another (its session cookie went too)
    if (refused && token && (auth === "valid" || auth === "viewer")) checkToken(token, true);
    return;
  }
  started = true;
  const found = takeTokenFromHash() || readStoredToken();
  if (found) checkToken(found);
  else setAuth("none");
});
