// The LIVE/REPLAY banner and the replay's controls (play, pause, step, speed, the time slider, back to live),
// shown while the station replays a recording. The replay is shared by every viewer, so its controls need the
// operator's token.

import { $, EVENTS, fmt, isNum, on, postWithAck, replayBlocker, setEnabled, setText, showHint } from "./common.js";

const SEEK_THROTTLE_MS = 250;
const CONTROLS = {
  "#replay-play": "Play or pause the replay",
  "#replay-back": "Step back",
  "#replay-step": "Step forward",
  "#replay-stop": "Leave the replay and show live vehicles",
};

let sliderHeld = false;     // the user is dragging the time slider: do not move it under them
let sliderQuietUntil = 0;   // after a seek, ignore stream times until the server has caught up

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

function updateControls(auth) {
  const reason = replayBlocker(auth);
  for (const [id, help] of Object.entries(CONTROLS)) setEnabled($(id), reason, help);
  $("#replay-speed").disabled = Boolean(reason);
  $("#replay-time").disabled = Boolean(reason);
  showHint($("#replay .replay-hint"), reason);
}

function replayControl(label, body) {
  return postWithAck($("#replay .ack"), label, "/api/replay/control", body);
}

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

on(EVENTS.auth, ({ auth }) => updateControls(auth));
on(EVENTS.status, (msg) => renderMode(msg.mode, msg.replay));
window.addEventListener("DOMContentLoaded", () => updateControls("none"));
