// "Go here": the ground point clicked in this page's 3D view or 2D map ("station-target") and the vehicle to send there,
// which follows the vehicle list and the operator's selection (operator.js sets it).

import {
  $, EVENTS, commandBlocker, el, fmt, on, postWithAck, setEnabled, showHint, vehicleName,
} from "./common.js";

let target = null;  // {x, y} picked in this viewer's 3D view
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
  coords.textContent = target ? `x ${fmt(target.x)} m, y ${fmt(target.y)} m` : "Click the ground in the 3D view or the 2D map to pick a target";
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
  postWithAck($("#target .ack"), `Go here (vehicle ${sysid})`,
    `/api/vehicles/${encodeURIComponent(sysid)}/commands`, { action: "goto", x: target.x, y: target.y });
});

on(EVENTS.target, ({ x, y }) => {
  target = { x, y };
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
  renderTargetVehicles();
  updateControls();
});
window.addEventListener("DOMContentLoaded", renderTarget);
