// The operator's view, panel side: which vehicle is selected (each vehicle in its own colour), the selected
// vehicle's instruments (attitude, heading, altitude, speed and climb, battery, its sonars as a proximity
// view) and a banner for every message at WARNING or worse. It draws from the status frames ("station-status")
// and says which vehicle is selected with window.selectedVehicle and a "vehicle-selected" event ({sysid}),
// which the 2D map, the plots, the 3D view and "Go here" follow (see common.js).
// Strings from vehicles go in with textContent only.

import { $, EVENTS, batteryText, el, emit, fmt, isNum, on } from "./common.js";

const WARNING = 4;          // MAVLink severity: WARNING, and 0..3 are worse
const SEVERE = 3;           // ERROR or worse
const WARNINGS_SHOWN = 3;
const WARNING_RECENT_S = 120;  // older warnings are not brought up when the page opens
const colourRe = /^#[0-9a-f]{6}$/i;

const MISSING_MS = 15000;
let vehicles = [];
const PROXIMITY_LADDER = [5, 10, 20, 40];  // m: the proximity ring's ranges, the nearest above the farthest echo
const ECHO_MEMORY_MS = 1500;  // the ring scales to the echoes of the last few seconds, so it does not flicker
const INSTRUMENT = 150;  // units across an instrument's face, whatever its size on the screen
const LABEL_PX = 11;  // the instruments' letters are at least this tall on screen
let echoes = [];  // recent echoes of the selected vehicle: {sysid, t, distance}
let missingSince = null;
const dismissed = new Set();
window.selectedVehicle = null;

function colourOf(v) {
  return v && typeof v.colour === "string" && colourRe.test(v.colour) ? v.colour : "#8d99a6";
}

function nameOf(v) {
  return `${v.sysid} ${v.type ? String(v.type) : "vehicle"}`;
}

// ---- selection ------------------------------------------------------------------------------
function select(sysid) {
  if (window.selectedVehicle === sysid) return;
  window.selectedVehicle = sysid;
  renderFleet();
  renderInstruments();
  emit(EVENTS.selected, { sysid });
}

function renderFleet() {
  const list = $("#fleet-list");
  const key = JSON.stringify(vehicles.map((v) => [v.sysid, v.type, v.mode, v.colour,
    v.agent && v.agent.state, v.agent && v.agent.reason, v.sysid === window.selectedVehicle]));
  if (list.dataset.key !== key) {
    list.dataset.key = key;
    list.replaceChildren(...vehicles.map((v) => {
      const li = el("li");
      const button = el("button", "fleet-item");
      button.type = "button";
      button.dataset.sysid = String(v.sysid);
      button.setAttribute("aria-pressed", String(v.sysid === window.selectedVehicle));
      const dot = el("span", "swatch-dot");
      dot.style.background = colourOf(v);
      const reason = v.agent && v.agent.reason ? `: ${String(v.agent.reason).slice(0, 80)}` : "";
      const agent = v.agent && v.agent.state ? ` · mission ${String(v.agent.state)}${reason}` : "";
      button.append(dot, el("span", "fleet-name", nameOf(v)), el("span", "fleet-mode", `${v.mode ?? "–"}${agent}`));
      button.addEventListener("click", () => select(v.sysid));
      li.append(button);
      return li;
    }));
    if (!vehicles.length) list.append(el("li", "empty", "No vehicles yet"));
  }
  // The vehicle cards (vehicles.js) in the same colours, the selected one outlined.
  for (const v of vehicles) {
    const card = document.querySelector(`.vehicle-card[data-sysid="${v.sysid}"]`);
    if (!card) continue;
    card.style.borderLeftColor = colourOf(v);
    card.classList.toggle("selected", v.sysid === window.selectedVehicle);
  }
}

// ---- warnings -------------------------------------------------------------------------------
function renderWarnings(now) {
  const found = [];
  for (const v of vehicles) {
    for (const m of Array.isArray(v.messages) ? v.messages : []) {
      if (!m || !isNum(m.severity) || m.severity > WARNING || !isNum(m.time)) continue;
      if (isNum(now) && now - m.time > WARNING_RECENT_S) continue;
      const key = `${v.sysid}|${m.time}|${m.text}`;
      if (!dismissed.has(key)) found.push({ key, v, m });
    }
  }
  found.sort((a, b) => b.m.time - a.m.time);
  const shown = found.slice(0, WARNINGS_SHOWN);
  const banner = $("#warning-banner");
  const key = JSON.stringify(shown.map((w) => w.key));
  if (banner.dataset.key === key) return;
  banner.dataset.key = key;
  banner.replaceChildren(...shown.map(({ key: id, v, m }) => {
    const li = el("li", m.severity <= SEVERE ? "severe" : "warning");
    const text = el("span", "warning-text");
    const who = el("strong", "warning-who", `${nameOf(v)}:`);
    who.style.color = colourOf(v);
    text.append(who, document.createTextNode(String(m.text ?? "")));
    const close = el("button", "btn btn-small", "Dismiss");
    close.type = "button";
    close.addEventListener("click", () => {
      dismissed.add(id);
      banner.dataset.key = "";
      renderWarnings(now);
    });
    li.append(text, close);
    return li;
  }));
  banner.hidden = shown.length === 0;
}

// ---- instruments ----------------------------------------------------------------------------
function selected() {
  return vehicles.find((v) => v.sysid === window.selectedVehicle) || null;
}

const LOOKS_DOWN = -5;  // degrees: a sonar pitched further down watches the ground (vehicle.world.suites)

/** A pitched sonar's mount beside its bearing (" up 8°", " down 10°"), so the overhead or ground sonar is not
 * taken for the level one at the same bearing; nothing for a level one. */
function mountPitch(pitch) {
  if (!isNum(pitch) || Math.abs(pitch) < 0.5) return "";
  return ` ${pitch > 0 ? "up" : "down"} ${Math.round(Math.abs(pitch))}°`;
}

function renderInstruments() {
  const v = selected();
  $("#instruments").hidden = !v;
  if (!v) return;
  const title = $("#instruments-vehicle");
  title.textContent = nameOf(v);
  title.style.color = colourOf(v);
  const alt = v.position && v.position.alt;
  $("#readout-altitude").textContent = isNum(alt) ? `${fmt(alt)} m` : "–";
  $("#readout-speed").textContent = isNum(v.speed) ? `${fmt(v.speed)} m/s` : "–";
  $("#readout-climb").textContent = isNum(v.climb) ? `${v.climb >= 0 ? "+" : ""}${fmt(v.climb)} m/s` : "–";
  $("#readout-heading").textContent = isNum(v.heading) ? `${Math.round(v.heading) % 360}°` : "–";
  const b = v.battery;
  $("#readout-battery").textContent = batteryText(b) + (b && isNum(b.current) ? ` · ${fmt(b.current)} A` : "");
  const sonars = Array.isArray(v.sonar) ? v.sonar : [];
  $("#readout-sonar").textContent = sonars.length ? sonars.map((s) =>
    `${Math.round(s.bearing ?? 0)}°${mountPitch(s.pitch)}: ${isNum(s.distance) && isNum(s.max_range)
      && s.distance < s.max_range ? `${fmt(s.distance)} m` : "clear"}`).join(" · ") : "none heard";
  const att = v.attitude || {};
  $("#readout-attitude").textContent = isNum(att.roll) && isNum(att.pitch)
    ? `roll ${fmt(att.roll)}°, pitch ${fmt(att.pitch)}°` : "–";
  drawAttitude($("#attitude"), isNum(att.roll) ? att.roll : 0, isNum(att.pitch) ? att.pitch : 0);
  drawCompass($("#compass"), isNum(v.heading) ? v.heading : null, colourOf(v));
  const around = sonars.filter((s) => !isNum(s.pitch) || s.pitch > LOOKS_DOWN);  // a ground sonar's echo is the
  // ground a metre or two ahead, at every step: in the ring it would look like an obstacle close ahead
  drawProximity($("#proximity"), around, colourOf(v), proximityRange(v.sysid, around));
}

/** An instrument's drawing surface: its canvas as many pixels as it shows on this screen (the instruments
 * grow with the panel, and stay sharp), drawn in INSTRUMENT units across whatever its size. */
function surface(canvas) {
  const shown = Math.round((canvas.clientWidth || INSTRUMENT) * (window.devicePixelRatio || 1));
  if (canvas.width !== shown) canvas.width = canvas.height = shown;
  const ctx = canvas.getContext("2d");
  const scale = shown / INSTRUMENT;
  ctx.setTransform(scale, 0, 0, scale, 0, 0);
  return { ctx, w: INSTRUMENT, h: INSTRUMENT, r: INSTRUMENT / 2 };
}

/** A font size (in INSTRUMENT units) that shows ``px`` tall on screen, however large the instrument is shown. */
function screenPx(canvas, px) {
  return Math.ceil(px * INSTRUMENT / (canvas.clientWidth || INSTRUMENT));
}

/** The proximity ring's range: the ladder's step just above the farthest echo of the last few seconds (the
 * nearest step when nothing echoes), so echoes at 7 to 11 m fill the ring rather than a corner of 40 m. */
function proximityRange(sysid, sonars) {
  const now = performance.now();
  echoes = echoes.filter((e) => e.sysid === sysid && now - e.t < ECHO_MEMORY_MS);
  for (const s of sonars) {
    if (s && isNum(s.distance) && isNum(s.max_range) && s.distance < s.max_range) {
      echoes.push({ sysid, t: now, distance: s.distance });
    }
  }
  const farthest = Math.max(0, ...echoes.map((e) => e.distance));
  return PROXIMITY_LADDER.find((step) => step > farthest) ?? PROXIMITY_LADDER[PROXIMITY_LADDER.length - 1];
}

/** An artificial horizon: sky and ground turned by the roll and shifted by the pitch, the aircraft fixed. */
function drawAttitude(canvas, roll, pitch) {
  const { ctx, w, h, r } = surface(canvas);
  const perDegree = r / 35;
  ctx.save();
  ctx.clearRect(0, 0, w, h);
  ctx.beginPath();
  ctx.arc(r, r, r - 1, 0, Math.PI * 2);
  ctx.clip();
  ctx.translate(r, r);
  ctx.rotate(-roll * Math.PI / 180);
  const shift = Math.max(-90, Math.min(90, pitch)) * perDegree;
  ctx.fillStyle = "#3a7bd5";
  ctx.fillRect(-2 * w, -4 * h + shift, 4 * w, 4 * h);
  ctx.fillStyle = "#8a5a2b";
  ctx.fillRect(-2 * w, shift, 4 * w, 4 * h);
  ctx.strokeStyle = "#ffffff";
  ctx.lineWidth = 2;
  ctx.beginPath();
  ctx.moveTo(-w, shift);
  ctx.lineTo(w, shift);
  ctx.stroke();
  ctx.lineWidth = 1;
  ctx.fillStyle = "#ffffff";
  ctx.font = "9px system-ui, sans-serif";
  for (let p = -30; p <= 30; p += 10) {  // the pitch ladder
    if (!p) continue;
    const y = shift - p * perDegree;
    const half = Math.abs(p) % 20 ? 10 : 18;
    ctx.beginPath();
    ctx.moveTo(-half, y);
    ctx.lineTo(half, y);
    ctx.stroke();
    ctx.fillText(String(Math.abs(p)), half + 3, y + 3);
  }
  ctx.restore();
  ctx.strokeStyle = "#ffd23f";  // the aircraft, fixed
  ctx.lineWidth = 3;
  ctx.beginPath();
  ctx.moveTo(r - 36, r);
  ctx.lineTo(r - 12, r);
  ctx.lineTo(r - 6, r + 6);
  ctx.moveTo(r + 36, r);
  ctx.lineTo(r + 12, r);
  ctx.lineTo(r + 6, r + 6);
  ctx.stroke();
  ctx.fillStyle = "#ffd23f";
  ctx.fillRect(r - 2, r - 2, 4, 4);
}

/** A compass rose turning under a fixed lubber line: the heading read at the top. */
function drawCompass(canvas, heading, colour) {
  const { ctx, w, r } = surface(canvas);
  ctx.clearRect(0, 0, w, w);
  ctx.fillStyle = "#0b0e11";
  ctx.beginPath();
  ctx.arc(r, r, r - 1, 0, Math.PI * 2);
  ctx.fill();
  ctx.save();
  ctx.translate(r, r);
  ctx.rotate(-(heading ?? 0) * Math.PI / 180);
  ctx.strokeStyle = "#8d99a6";
  ctx.fillStyle = "#dde3ea";
  ctx.textAlign = "center";
  ctx.textBaseline = "middle";
  ctx.font = `bold ${screenPx(canvas, LABEL_PX + 1)}px system-ui, sans-serif`;
  for (let d = 0; d < 360; d += 10) {
    const a = d * Math.PI / 180;
    const long = d % 30 === 0;
    ctx.beginPath();
    ctx.moveTo(Math.sin(a) * (r - 3), -Math.cos(a) * (r - 3));
    ctx.lineTo(Math.sin(a) * (r - (long ? 12 : 7)), -Math.cos(a) * (r - (long ? 12 : 7)));
    ctx.stroke();
    if (d % 90 === 0) {
      ctx.fillStyle = d === 0 ? "#f06a6a" : "#dde3ea";
      ctx.fillText("NESW"[d / 90], Math.sin(a) * (r - 22), -Math.cos(a) * (r - 22));
    }
  }
  ctx.restore();
  ctx.fillStyle = colour;  // the vehicle, nose up
  ctx.beginPath();
  ctx.moveTo(r, r - 18);
  ctx.lineTo(r + 10, r + 12);
  ctx.lineTo(r, r + 6);
  ctx.lineTo(r - 10, r + 12);
  ctx.closePath();
  ctx.fill();
  ctx.fillStyle = "#ffd23f";
  ctx.beginPath();
  ctx.moveTo(r, 12);
  ctx.lineTo(r - 5, 2);
  ctx.lineTo(r + 5, 2);
  ctx.fill();
  ctx.fillStyle = "#ffffff";
  ctx.font = "bold 13px system-ui, sans-serif";
  ctx.textAlign = "center";
  ctx.fillText(heading == null ? "–" : `${String(Math.round(heading) % 360).padStart(3, "0")}°`, r, r + 36);
  ctx.textAlign = "start";
}

/** The colour of a sonar sector by how near its echo is (as QGroundControl's proximity radar). */
function proximityColour(s) {
  if (!isNum(s.distance) || !isNum(s.max_range) || s.distance >= s.max_range) return "rgba(98, 196, 124, 0.35)";
  if (s.distance < 1.5) return "#f0403a";
  if (s.distance < 3) return "#f08a24";
  if (s.distance < 6) return "#e8d23d";
  return "#62c47c";
}

/** The sonars seen from above, nose up: each a sector at its bearing and beam width, as long as its echo
 * (clear to its range when there is none), coloured by distance. */
/** The sonars around the vehicle out to ``range`` metres: an echo is a sector as long as its distance, a clear
 * sonar (or an echo beyond the range) a sector to the ring's edge. */
function drawProximity(canvas, sonars, colour, range) {
  const { ctx, w, r } = surface(canvas);
  const scale = (r - 6) / range;
  canvas.dataset.range = String(range);
  canvas.dataset.sonars = String(sonars.length);  // how many sectors it shows
  ctx.clearRect(0, 0, w, w);
  ctx.fillStyle = "#0b0e11";
  ctx.beginPath();
  ctx.arc(r, r, r - 1, 0, Math.PI * 2);
  ctx.fill();
  ctx.strokeStyle = "#2b333d";
  for (const f of [0.25, 0.5, 0.75, 1]) {
    ctx.beginPath();
    ctx.arc(r, r, (r - 6) * f, 0, Math.PI * 2);
    ctx.stroke();
  }
  for (const s of sonars) {
    if (!s || !isNum(s.bearing)) continue;
    const half = Math.max(6, isNum(s.beam) ? s.beam / 2 : 10) * Math.PI / 180;  // narrow beams still show
    const a = s.bearing * Math.PI / 180 - Math.PI / 2;  // canvas angle: 0 east, clockwise; bearing 0 is up
    const near = isNum(s.distance) && isNum(s.max_range) && s.distance < s.max_range;
    const length = Math.max(4, Math.min(near ? s.distance : range, range) * scale);
    ctx.fillStyle = proximityColour(s);
    ctx.beginPath();
    ctx.moveTo(r, r);
    ctx.arc(r, r, length, a - half, a + half);
    ctx.closePath();
    ctx.fill();
  }
  ctx.fillStyle = colour;
  ctx.beginPath();
  ctx.moveTo(r, r - 8);
  ctx.lineTo(r + 5, r + 6);
  ctx.lineTo(r - 5, r + 6);
  ctx.fill();
  ctx.fillStyle = "#8d99a6";
  ctx.font = `${screenPx(canvas, LABEL_PX)}px system-ui, sans-serif`;
  ctx.textAlign = "center";
  ctx.fillText(`${range} m`, r, w - 6);
  ctx.textAlign = "start";
}

// ---- the stream ----------------------------------------------------------------------------
on(EVENTS.status, (msg) => {
  vehicles = (Array.isArray(msg.vehicles) ? msg.vehicles : []).filter((v) => v && Number.isInteger(v.sysid));
  const ids = vehicles.map((v) => v.sysid);
  // The first vehicle heard is selected until the operator picks one; a selected vehicle that goes missing
  // (a replay seeking before it was heard, a link down) stays selected a while, then the first is.
  if (ids.includes(window.selectedVehicle)) {
    missingSince = null;
  } else if (window.selectedVehicle == null) {
    if (ids.length) select(ids[0]);
  } else if (ids.length) {
    missingSince = missingSince ?? performance.now();
    if (performance.now() - missingSince > MISSING_MS) select(ids[0]);
  }
  renderFleet();
  renderInstruments();
  renderWarnings(msg.time);
});
