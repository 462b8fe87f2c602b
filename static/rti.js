// Radio tomography: the station's live image (GET /api/rti, /api/rti/image) asked for with the status frames,
// at most every ASK_MS, the image only when a new frame was made. The RTI panel shows links per second,
// coverage and the peaks' positions; the image itself, its colour bar, the peaks, the last window's links and
// the simulated targets are drawn by map2d.js, told by "rti-frame" (see common.js). Hidden while the station
// has imaged nothing (no radio records): an empty answer, not an error.

import { $, EVENTS, emit, fmt, getJson, isNum, loadImage, on, validBounds } from "./common.js";

const ASK_MS = 500;

let asking = false;
let askedAt = 0;
let shownT = null;     // the frame whose image is loaded
let picture = null;    // {bounds, img, scale}
let mode = null;

function points(list) {
  return Array.isArray(list) ? list.filter((p) => p && isNum(p.x) && isNum(p.y)) : [];
}

async function ask() {
  asking = true;
  askedAt = Date.now();
  try {
    const answer = await getJson("/api/rti");
    const frame = answer && answer.frame && validBounds(answer.frame.bounds) ? answer.frame : null;
    if (!frame) {
      if (shownT !== null || picture) emit(EVENTS.rti, { frame: null, picture: null, targets: [] });
      shownT = null;
      picture = null;
      show(null, answer);
      return;
    }
    if (frame.t !== shownT) {
      const drawn = await getJson("/api/rti/image");
      if (drawn && typeof drawn.image === "string" && validBounds(drawn.bounds)) {
        picture = { bounds: drawn.bounds, img: await loadImage(drawn.image), scale: drawn.scale || {} };
        shownT = frame.t;
      }
    }
    const targets = Array.isArray(answer.targets)
      ? answer.targets.filter((p) => Array.isArray(p) && isNum(p[0]) && isNum(p[1])) : [];
    emit(EVENTS.rti, { frame: { ...frame, peaks: points(frame.peaks) }, picture, targets });
    show(frame, answer);
  } finally {
    asking = false;
  }
}

function show(frame, answer) {
  const panel = $("#rti");
  panel.hidden = !frame;
  if (!frame) return;
  $("#rti-links").textContent = `${fmt(frame.links_per_s, 0)} /s`;
  $("#rti-coverage").textContent = isNum(frame.coverage) ? `${fmt(frame.coverage * 100, 0)} %` : "–";
  $("#rti-time").textContent = `${fmt(frame.t, 1)} s`;
  $("#rti-latency").textContent = isNum(frame.latency_s) ? `${fmt(frame.latency_s, 2)} s` : "–";
  const list = $("#rti-peaks");
  list.replaceChildren(...points(frame.peaks).map((p) => {
    const item = document.createElement("li");
    item.textContent = `x ${fmt(p.x, 2)} m, y ${fmt(p.y, 2)} m (${fmt(p.value, 3)})`;
    return item;
  }));
  if (!list.children.length) list.textContent = "none";
  $("#rti-error").textContent = answer && answer.error ? `last frame failed: ${answer.error}` : "";
}

on(EVENTS.status, (msg) => {
  const now = `${msg.mode}|${msg.replay && msg.replay.name ? msg.replay.name : ""}`;
  if (now !== mode) {  // live <-> replay: another log, another image
    mode = now;
    shownT = null;
  }
  if (!asking && Date.now() - askedAt >= ASK_MS) ask();
});
