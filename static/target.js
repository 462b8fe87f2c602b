// "Go here": the ground point clicked in this page's 3D view or 2D map ("station-target") and the vehicle to send there,
// which follows the vehicle list and the operator's selection (operator.js sets it). The target is this page's until
// the vehicle sent there reaches it ("station-target-done": the 2D map and the 3D view take their marks away) or
// another pick replaces it; a vehicle merely passing over it does not take it away.

import {
  $, EVENTS, commandBlocker, el, emit, fmt, isNum, on, postWithAck, setEnabled, showHint, vehicleName,
} from "./common.js";

const REACHED_M = 1.0;  // across the ground: the vehicle sent to the target is there
let target = null;  // {x, y} picked in this viewer's 3D view or on its 2D map
let sent = null;    // the sysid of the vehicle Go here sent to the target, once it accepted
let reached = "";   // what the last target's end was, said until the next pick
let vehicles = [];
let auth = "none";
let mode = "live";

function updateControls() {
  const reason = commandBlocker(auth, mode);
  const missing = !target ? "Click the ground in the 3D view or the 2D map first" : !vehicles.length ? "No vehicle to send" : "";
  setEnabled($("#go-here"), reason || missing, "Send the selected vehicle to the target");
  showHint($("#target .command-hint"), reason);
}

function renderTarget() {
  const coords = $("#target-coords");
  coords.textContent = target ? `x ${fmt(target.x)} m, y ${fmt(target.y)} m`
    : `${reached}Click the ground in the 3D view or the 2D map to pick a target`;
  coords.classList.toggle("has-target", Boolean(target));
  updateControls();
}

/** Keep the vehicle selector in step with the vehicle list, keeping the user's choice. */
function renderTargetVehicles() {
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

$("#go-here").addEventListener("click", () => {
  const sysid = $("#target-vehicle").value;
  if (!target || !sysid) return;
  const picked = target;
  postWithAck($("#target .ack"), `Go here (vehicle ${sysid})`,
    `/api/vehicles/${encodeURIComponent(sysid)}/commands`, { action: "goto", x: target.x, y: target.y })
    .then(({ data }) => {
      if (target === picked && data && data.result === "accepted") sent = Number(sysid);
    });
});

/** The vehicle sent to the target is there: the target is done, and every mark of it goes. */
function watchArrival(list) {
  if (!target || sent == null) return;
  const v = list.find((one) => one.sysid === sent);
  const p = v && v.position;
  if (!p || !isNum(p.x) || !isNum(p.y) || Math.hypot(p.x - target.x, p.y - target.y) >= REACHED_M) return;
  reached = `${vehicleName(v)} reached x ${fmt(target.x)} m, y ${fmt(target.y)} m. `;
  target = null;
  sent = null;
  renderTarget();
  emit(EVENTS.targetDone, { reason: reached });
}

on(EVENTS.target, ({ x, y }) => {
  target = { x, y };
  sent = null;  // a new target: nobody has been sent to it yet
  renderTarget();
});
// "Go here" follows the operator's selection (operator.js)
on(EVENTS.selected, ({ sysid }) => {
  const select = $("#target-vehicle");
  if (sysid != null && Array.from(select.options).some((o) => o.value === String(sysid))) select.value = String(sysid);
});
on(EVENTS.auth, (detail) => {
  auth = detail.auth;
  updateControls();
});
on(EVENTS.status, (msg) => {
  mode = msg.mode;
  vehicles = msg.vehicles;
  watchArrival(vehicles);
  renderTargetVehicles();
  updateControls();
});
window.addEventListener("DOMContentLoaded", renderTarget);
