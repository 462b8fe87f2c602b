// The 2D map beside the 3D view: the scene from above, the memory map (the selected vehicle's or all of them
// merged), every vehicle in its colour with its heading, trail, waypoints and planned path; a scale bar, a
// north arrow, the coordinates under the cursor and a distance tool (Measure, then click two points).
// Drag to pan, wheel to zoom towards the cursor. Scene metres: x east, y north. Pictures come as PNG data
// URLs from /api/map2d/*; vehicles from the status frames ("station-status", see common.js). While the plan view
// edits (plan.js), a click is a new waypoint ("map2d-click") and a waypoint dragged moves it ("plan-move"); the
// plan is drawn with its legs, a leg the scene blocks in red. The radio tomography's image (rti.js, "rti-frame")
// is a layer over the maps with its colour bar, the last window's links as faint lines, its peaks as crosses with
// their value and the simulated targets (ground truth) as rings.

import { $, EVENTS, emit, fmt, getJson, isNum, loadImage, on, validBounds } from "./common.js";

const POLL_MS = 2000;  // memory maps and trails
const colourRe = /^#[0-9a-f]{6}$/i;

const canvas = $("#map2d");
const ctx = canvas.getContext("2d");
const view = { cx: 0, cy: 0, scale: 4, fitted: false };  // centre (m) and pixels per metre
let scene = null;      // {bounds, img}
let overlay = null;    // {bounds, img}
let rti = { frame: null, picture: null, targets: [] };  // "rti-frame"
let trails = {};
let vehicles = [];
let mode = null;
let measuring = false;
let measure = [];      // up to two [x, y]
let drag = null;
let cursor = null;
let plan = { editing: false, items: [], legs: [], home: null, selected: null, current: null };
let target = null;     // [x, y]: the Go here target picked here or in the 3D view, until reached (target.js)
let following = false; // the view keeps the selected vehicle in its middle
const GRAB_PX = 10;  // a plan item this close to the pointer is dragged, not the map
const map2d = { view, measure, get distance() { return distance(); }, toScreen: (x, y) => toScreen(x, y) };
window.map2d = map2d;  // what the map shows, for tests and the page's other scripts

async function loadScene() {
  const found = await getJson("/api/map2d/scene");
  scene = found && validBounds(found.bounds) && typeof found.image === "string"
    ? { bounds: found.bounds, img: await loadImage(found.image) } : null;
  if (!view.fitted) fit();
  draw();
}

let lastOverlayUrl = "";
async function loadOverlay() {
  const layer = $("#map2d-layer").value;
  const which = layer === "merged" ? "merged" : layer === "selected" && Number.isInteger(window.selectedVehicle)
    ? String(window.selectedVehicle) : null;
  // asked for only once the status frames say such a map exists (the station answers 404 before, and the
  // browser logs every 404 as an error in the console)
  const held = mapsHeld();
  const exists = which === "merged" ? held.length > 0 : held.includes(which);
  const found = exists ? await getJson(`/api/map2d/maps/${which}`) : null;
  if (!found || !validBounds(found.bounds) || typeof found.image !== "string") {
    overlay = null;
    lastOverlayUrl = "";
  } else if (found.image !== lastOverlayUrl) {
    lastOverlayUrl = found.image;
    overlay = { bounds: found.bounds, img: await loadImage(found.image), which };
  }
  canvas.dataset.overlay = overlay ? overlay.which : "";
  draw();
}

/** The vehicles (system ids, as text) whose status says they hold a memory map. */
function mapsHeld() {
  return vehicles.filter((v) => v.map && isNum(v.map.occupied)).map((v) => String(v.sysid));
}

async function loadTrails() {
  const found = await getJson("/api/map2d/trails");
  trails = found && typeof found === "object" ? found : {};
  draw();
}

function poll() {
  if (document.hidden || $("#map2d-pane").classList.contains("collapsed")) return;
  loadOverlay();
  loadTrails();
}

// ---- geometry -------------------------------------------------------------------------------
function size() {
  const rect = canvas.getBoundingClientRect();
  const ratio = window.devicePixelRatio || 1;
  const w = Math.max(1, Math.round(rect.width * ratio)), h = Math.max(1, Math.round(rect.height * ratio));
  if (canvas.width !== w || canvas.height !== h) {
    canvas.width = w;
    canvas.height = h;
  }
  return { w: rect.width, h: rect.height, ratio };
}

function toScreen(x, y) {
  const { w, h } = size();
  return [w / 2 + (x - view.cx) * view.scale, h / 2 - (y - view.cy) * view.scale];
}

function toScene(px, py) {
  const { w, h } = size();
  return [view.cx + (px - w / 2) / view.scale, view.cy - (py - h / 2) / view.scale];
}

function fit() {
  let b = scene && scene.bounds;
  if (!b) {
    const points = vehicles.filter((v) => v.position).map((v) => [v.position.x, v.position.y]);
    if (!points.length) return;
    const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
    b = [Math.min(...xs) - 20, Math.min(...ys) - 20, Math.max(...xs) + 20, Math.max(...ys) + 20];
  }
  const { w, h } = size();
  view.cx = (b[0] + b[2]) / 2;
  view.cy = (b[1] + b[3]) / 2;
  view.scale = Math.max(0.01, Math.min(w / (b[2] - b[0]), h / (b[3] - b[1])) * 0.95);
  view.fitted = true;
}

function distance() {
  return measure.length === 2 ? Math.hypot(measure[1][0] - measure[0][0], measure[1][1] - measure[0][1]) : null;
}

// ---- drawing ------------------------------------------------------------------------------
function drawImage(picture) {
  if (!picture || !picture.img) return;
  const [west, south, east, north] = picture.bounds;
  const [x0, y0] = toScreen(west, north);
  const [x1, y1] = toScreen(east, south);
  ctx.imageSmoothingEnabled = false;
  ctx.drawImage(picture.img, x0, y0, x1 - x0, y1 - y0);
}

function colourOf(v) {
  return typeof v.colour === "string" && colourRe.test(v.colour) ? v.colour : "#8d99a6";
}

function polyline(points, colour, width, dash) {
  if (!Array.isArray(points) || points.length < 2) return;
  ctx.strokeStyle = colour;
  ctx.lineWidth = width;
  ctx.setLineDash(dash || []);
  ctx.beginPath();
  points.forEach((p, i) => {
    if (!Array.isArray(p) || !isNum(p[0]) || !isNum(p[1])) return;
    const [sx, sy] = toScreen(p[0], p[1]);
    if (i === 0) ctx.moveTo(sx, sy); else ctx.lineTo(sx, sy);
  });
  ctx.stroke();
  ctx.setLineDash([]);
}

function drawVehicle(v) {
  const p = v.position;
  if (!p || !isNum(p.x) || !isNum(p.y)) return;
  const [sx, sy] = toScreen(p.x, p.y);
  const selected = v.sysid === window.selectedVehicle;
  const heading = (isNum(v.heading) ? v.heading : 0) * Math.PI / 180;
  ctx.save();
  ctx.translate(sx, sy);
  if (selected) {
    ctx.strokeStyle = "#ffffff";
    ctx.lineWidth = 2;
    ctx.beginPath();
    ctx.arc(0, 0, 13, 0, Math.PI * 2);
    ctx.stroke();
  }
  ctx.rotate(heading);
  ctx.fillStyle = colourOf(v);
  ctx.strokeStyle = "#0b0e11";
  ctx.lineWidth = 1.5;
  ctx.beginPath();
  ctx.moveTo(0, -10);
  ctx.lineTo(7, 8);
  ctx.lineTo(0, 4);
  ctx.lineTo(-7, 8);
  ctx.closePath();
  ctx.fill();
  ctx.stroke();
  ctx.restore();
  ctx.fillStyle = colourOf(v);
  ctx.font = "bold 11px system-ui, sans-serif";
  ctx.fillText(String(v.sysid), sx + 12, sy - 8);
}

/** A scale bar of a round length (1, 2 or 5 x 10^n m) about a fifth of the map wide. */
function drawScale(w, h) {
  const target = w / 5 / view.scale;
  const power = 10 ** Math.floor(Math.log10(target));
  const metres = [5, 2, 1].map((f) => f * power).find((m) => m <= target) || power;
  const px = metres * view.scale;
  const x = 12, y = h - 14;
  ctx.strokeStyle = "#ffffff";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(x, y - 5);
  ctx.lineTo(x, y);
  ctx.lineTo(x + px, y);
  ctx.lineTo(x + px, y - 5);
  ctx.stroke();
  ctx.fillStyle = "#ffffff";
  ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(metres >= 1000 ? `${metres / 1000} km` : `${metres} m`, x + px + 6, y + 3);
  canvas.dataset.scale = String(metres);
}

function drawNorth(w) {
  const x = w - 22, y = 30;
  ctx.fillStyle = "#ffffff";
  ctx.beginPath();
  ctx.moveTo(x, y - 14);
  ctx.lineTo(x + 7, y + 6);
  ctx.lineTo(x, y + 1);
  ctx.lineTo(x - 7, y + 6);
  ctx.closePath();
  ctx.fill();
  ctx.font = "bold 12px system-ui, sans-serif";
  ctx.textAlign = "center";
  ctx.fillText("N", x, y + 20);
  ctx.textAlign = "start";
}

function drawMeasure() {
  if (!measure.length) return;
  ctx.strokeStyle = "#e8a33d";
  ctx.fillStyle = "#e8a33d";
  ctx.lineWidth = 2;
  const points = measure.map((p) => toScreen(p[0], p[1]));
  for (const [sx, sy] of points) {
    ctx.beginPath();
    ctx.arc(sx, sy, 4, 0, Math.PI * 2);
    ctx.fill();
  }
  if (points.length === 2) {
    ctx.beginPath();
    ctx.moveTo(...points[0]);
    ctx.lineTo(...points[1]);
    ctx.stroke();
    const d = distance();
    ctx.font = "bold 12px system-ui, sans-serif";
    ctx.fillText(`${fmt(d)} m`, (points[0][0] + points[1][0]) / 2 + 6, (points[0][1] + points[1][1]) / 2 - 6);
  }
}

function draw() {
  const { w, h, ratio } = size();
  const chased = following && vehicles.find((v) => v.sysid === window.selectedVehicle);
  if (chased && chased.position && isNum(chased.position.x) && isNum(chased.position.y)) {
    view.cx = chased.position.x;
    view.cy = chased.position.y;
  }
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.fillStyle = "#0b0e11";
  ctx.fillRect(0, 0, w, h);
  drawImage(scene);
  drawImage(overlay);
  drawRti(w);
  for (const v of vehicles) {
    polyline(trails[String(v.sysid)], colourOf(v), 1.5);
    polyline(v.waypoints, "rgba(255, 255, 255, 0.7)", 1, [4, 4]);
    for (const p of Array.isArray(v.waypoints) ? v.waypoints : []) {
      if (!Array.isArray(p) || !isNum(p[0]) || !isNum(p[1])) continue;
      const [sx, sy] = toScreen(p[0], p[1]);
      ctx.strokeStyle = "#ffffff";
      ctx.strokeRect(sx - 3, sy - 3, 6, 6);
    }
    polyline(v.path, "#ffd23f", 2);
  }
  drawPlan();
  drawTarget();
  for (const v of vehicles) drawVehicle(v);
  drawMeasure();
  drawScale(w, h);
  drawNorth(w);
}

/** The Go here target: a yellow ring with a cross, as the 3D view's marker. */
function drawTarget() {
  if (!target) return;
  const [sx, sy] = toScreen(target[0], target[1]);
  ctx.strokeStyle = "#ffd23f";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.arc(sx, sy, 9, 0, Math.PI * 2);
  ctx.moveTo(sx - 5, sy);
  ctx.lineTo(sx + 5, sy);
  ctx.moveTo(sx, sy - 5);
  ctx.lineTo(sx, sy + 5);
  ctx.stroke();
  ctx.lineWidth = 1;
}

/** The radio tomography layer: the image, the last window's links, the targets, the peaks, the colour bar. */
function drawRti(w) {
  const { frame, picture, targets } = rti;
  canvas.dataset.rti = frame ? String(frame.t) : "";
  if (!frame) return;
  ctx.globalAlpha = 0.85;
  drawImage(picture);
  ctx.globalAlpha = 1;
  for (const link of Array.isArray(frame.links) ? frame.links : []) {
    if (Array.isArray(link) && link.length === 4 && link.every(isNum)) {
      polyline([[link[0], link[1]], [link[2], link[3]]], "rgba(255, 255, 255, 0.18)", 1);
    }
  }
  ctx.lineWidth = 2;
  for (const [x, y] of targets) {
    const [sx, sy] = toScreen(x, y);
    ctx.strokeStyle = "#39c5ff";
    ctx.beginPath();
    ctx.arc(sx, sy, 9, 0, Math.PI * 2);
    ctx.stroke();
  }
  ctx.font = "bold 11px system-ui, sans-serif";
  frame.peaks.forEach((p, i) => {
    const [sx, sy] = toScreen(p.x, p.y);
    ctx.strokeStyle = "#ff4d4f";
    ctx.lineWidth = 3;
    ctx.beginPath();
    ctx.moveTo(sx - 6, sy - 6); ctx.lineTo(sx + 6, sy + 6);
    ctx.moveTo(sx - 6, sy + 6); ctx.lineTo(sx + 6, sy - 6);
    ctx.stroke();
    ctx.fillStyle = "#ffffff";
    ctx.fillText(`${i + 1}: ${fmt(p.value, 3)}`, sx + 9, sy - 7);
  });
  canvas.dataset.rtiPeaks = String(frame.peaks.length);
  if (picture && picture.scale) drawColourBar(w, picture.scale, targets.length > 0);
}

/** The image's colour bar (0 at the bottom, the image's maximum at the top, in its unit) and the legend. */
function drawColourBar(w, scale, truth) {
  const colours = Array.isArray(scale.colours) ? scale.colours.filter((c) => colourRe.test(c)) : [];
  if (colours.length < 2 || !isNum(scale.max)) return;
  const x = w - 34, top = 62, height = 110;
  const ramp = ctx.createLinearGradient(0, top + height, 0, top);
  colours.forEach((c, i) => ramp.addColorStop(i / (colours.length - 1), c));
  ctx.fillStyle = ramp;
  ctx.fillRect(x, top, 12, height);
  ctx.strokeStyle = "#ffffff";
  ctx.lineWidth = 1;
  ctx.strokeRect(x, top, 12, height);
  ctx.fillStyle = "#ffffff";
  ctx.font = "10px system-ui, sans-serif";
  ctx.textAlign = "right";
  ctx.fillText(fmt(scale.max, 3), x - 3, top + 8);
  ctx.fillText("0", x - 3, top + height);
  ctx.fillText(String(scale.unit || ""), x + 12, top - 6);
  const legend = ["× peak", "— link", ...(truth ? ["○ target"] : [])];
  legend.forEach((text, i) => ctx.fillText(text, x + 12, top + height + 14 + i * 12));
  ctx.textAlign = "start";
  canvas.dataset.rtiBar = fmt(scale.max, 3);
}

const PLAN_LABELS = { takeoff: "T", land: "L", rtl: "R", loiter: "O" };

/** The plan: its legs from home (red where the scene blocks one), each item a numbered disc. */
function drawPlan() {
  const items = plan.items.filter((p) => isNum(p.x) && isNum(p.y));
  if (!items.length) return;
  let from = plan.home || [items[0].x, items[0].y];
  plan.items.forEach((p, i) => {
    const to = p.action === "rtl" && plan.home ? plan.home : [p.x, p.y];
    const blocked = plan.legs[i] && plan.legs[i].blocked;
    polyline([from, to], blocked ? "#ff4d4f" : "#39c5ff", blocked ? 4 : 2, blocked ? [] : [6, 3]);
    from = to;
  });
  plan.items.forEach((p, i) => {
    if (p.action === "rtl") return;
    const [sx, sy] = toScreen(p.x, p.y);
    ctx.beginPath();
    ctx.arc(sx, sy, 8, 0, Math.PI * 2);
    ctx.fillStyle = i === plan.current ? "#ffd23f" : "#0f6e99";
    ctx.fill();
    ctx.lineWidth = i === plan.selected ? 3 : 1.5;
    ctx.strokeStyle = i === plan.selected ? "#ffffff" : "#bfefff";
    ctx.stroke();
    ctx.fillStyle = i === plan.current ? "#0b0e11" : "#ffffff";
    ctx.font = "bold 10px system-ui, sans-serif";
    ctx.textAlign = "center";
    ctx.fillText(PLAN_LABELS[p.action] || String(i + 1), sx, sy + 3.5);
    ctx.textAlign = "start";
  });
}

/** The plan item under the pointer (within GRAB_PX), or null. */
function planItemAt(px, py) {
  let best = null, bestDistance = GRAB_PX;
  plan.items.forEach((p, i) => {
    if (p.action === "rtl") return;
    const [sx, sy] = toScreen(p.x, p.y);
    const d = Math.hypot(sx - px, sy - py);
    if (d <= bestDistance) { best = i; bestDistance = d; }
  });
  return best;
}

// ---- interaction --------------------------------------------------------------------------
function local(event) {
  const rect = canvas.getBoundingClientRect();
  return [event.clientX - rect.left, event.clientY - rect.top];
}

function showDistance() {
  const d = distance();
  $("#map2d-distance").textContent = d == null ? (measuring ? (measure.length ? "click the second point"
    : "click the first point") : "") : `distance ${fmt(d)} m`;
}

canvas.addEventListener("pointerdown", (event) => {
  const item = plan.editing && !measuring ? planItemAt(...local(event)) : null;
  drag = { start: local(event), cx: view.cx, cy: view.cy, moved: false, item };
  canvas.setPointerCapture(event.pointerId);
});
canvas.addEventListener("pointermove", (event) => {
  const [px, py] = local(event);
  cursor = toScene(px, py);
  $("#map2d-cursor").textContent = `x ${fmt(cursor[0])} m, y ${fmt(cursor[1])} m`;
  if (drag) {
    const dx = px - drag.start[0], dy = py - drag.start[1];
    if (Math.hypot(dx, dy) > 4) drag.moved = true;
    if (drag.moved && drag.item !== null) {
      emit(EVENTS.planMove, { index: drag.item, x: cursor[0], y: cursor[1], done: false });
    } else if (drag.moved) {
      setFollowing(false);  // the operator looks elsewhere
      view.cx = drag.cx - dx / view.scale;
      view.cy = drag.cy + dy / view.scale;
      draw();
    }
  }
});
canvas.addEventListener("pointerup", (event) => {
  const wasDrag = drag && drag.moved;
  const item = drag ? drag.item : null;
  drag = null;
  const [px, py] = local(event);
  if (wasDrag && item !== null) {
    const [x, y] = toScene(px, py);
    emit(EVENTS.planMove, { index: item, x, y, done: true });
    return;
  }
  if (!wasDrag && !measuring && plan.editing && item === null) {
    const [x, y] = toScene(px, py);
    emit(EVENTS.mapClick, { x, y });
    return;
  }
  if (!wasDrag && !measuring && !plan.editing) {  // a plain click picks the Go here target, as in the 3D view
    const [x, y] = toScene(px, py);
    emit(EVENTS.target, { x, y });
    return;
  }
  if (wasDrag || !measuring) return;
  if (measure.length >= 2) measure.length = 0;
  measure.push(toScene(px, py));
  showDistance();
  draw();
});
canvas.addEventListener("wheel", (event) => {
  event.preventDefault();
  const [px, py] = local(event);
  const before = toScene(px, py);
  view.scale = Math.max(0.01, Math.min(500, view.scale * Math.exp(-event.deltaY * 0.0015)));
  const after = toScene(px, py);  // keep the point under the cursor where it was
  view.cx += before[0] - after[0];
  view.cy += before[1] - after[1];
  draw();
}, { passive: false });

$("#map2d-measure").addEventListener("click", () => {
  measuring = !measuring;
  measure.length = 0;
  $("#map2d-measure").setAttribute("aria-pressed", String(measuring));
  canvas.classList.toggle("measuring", measuring);
  showDistance();
  draw();
});
$("#map2d-fit").addEventListener("click", () => { setFollowing(false); fit(); draw(); });
function setFollowing(on) {
  following = on;
  $("#map2d-follow").setAttribute("aria-pressed", String(on));
}
$("#map2d-follow").addEventListener("click", () => { setFollowing(!following); draw(); });
on(EVENTS.target, ({ x, y }) => {
  target = isNum(x) && isNum(y) ? [x, y] : null;
  draw();
});
on(EVENTS.targetDone, () => {
  target = null;
  draw();
});
/** Swapped, the map fills the view area and the 3D view sits in its corner; a hidden map gives it all back. */
function placeViews() {
  const pane = $("#map2d-pane");
  pane.parentElement.classList.toggle("map-first", pane.classList.contains("large")
    && !pane.classList.contains("collapsed"));
}
$("#map2d-grow").addEventListener("click", () => {
  const large = $("#map2d-pane").classList.toggle("large");
  placeViews();
  $("#map2d-grow").setAttribute("aria-pressed", String(large));
  $("#map2d-grow").title = large ? "Swap back: the 3D view large, the map in its corner"
    : "Swap: the map large, the 3D view in its corner";
  fit();
  draw();
});
$("#map2d-layer").addEventListener("change", loadOverlay);
$("#map2d-toggle").addEventListener("click", () => {
  const pane = $("#map2d-pane");
  const collapsed = pane.classList.toggle("collapsed");
  placeViews();
  $("#map2d-toggle").setAttribute("aria-expanded", String(!collapsed));
  $("#map2d-toggle").textContent = collapsed ? "+" : "–";
  $("#map2d-toggle").title = collapsed ? "Show the 2D map" : "Hide the 2D map";
  if (!collapsed) { poll(); draw(); }
});
window.addEventListener("resize", draw);
on(EVENTS.plan, (detail) => {
  plan = { editing: Boolean(detail.editing), items: Array.isArray(detail.items) ? detail.items : [],
           legs: Array.isArray(detail.legs) ? detail.legs : [], home: detail.home || null,
           selected: detail.selected ?? null, current: detail.current ?? null };
  canvas.classList.toggle("planning", plan.editing);
  draw();
});
on(EVENTS.selected, () => { loadOverlay(); draw(); });
on(EVENTS.rti, (detail) => {
  rti = { frame: detail.frame || null, picture: detail.picture || null,
          targets: Array.isArray(detail.targets) ? detail.targets : [] };
  draw();
});
on(EVENTS.status, (msg) => {
  const held = mapsHeld().join();
  vehicles = msg.vehicles.filter((v) => Number.isInteger(v.sysid));
  if (mapsHeld().join() !== held) loadOverlay();  // a map appeared (or went): no need to wait for the poll
  const replay = msg.replay && msg.replay.scene ? JSON.stringify(msg.replay.scene) : "";
  const now = `${msg.mode}|${replay}`;
  if (now !== mode) {  // live and each replay may show another scene
    mode = now;
    view.fitted = false;
    loadScene();
    poll();
  }
  if (!view.fitted) fit();
  draw();
});
setInterval(poll, POLL_MS);
draw();
