// The recordings list: each recording's duration, size and date, a Replay button (which needs the operator's
// token: the replay is shared by every viewer) and a Download link. The status frames list recordings live
// (sizes and durations grow, new sessions appear); the list is fetched whole when the panel opens, on Refresh,
// when live and replay swap, and when watching becomes possible.

import { $, EVENTS, api, el, isNum, on, postWithAck, replayBlocker, setEnabled, setText, showHint } from "./common.js";

let auth = "none";
let mode = "live";  // as the stream last said

function formatSize(bytes) {
  if (!isNum(bytes)) return "";
  if (bytes < 1024) return `${bytes} B`;
  if (bytes < 1024 * 1024) return `${(bytes / 1024).toFixed(0)} kB`;
  return `${(bytes / 1024 / 1024).toFixed(1)} MB`;
}

function formatDuration(s) {
  if (!isNum(s)) return "";
  const total = Math.round(s);
  const h = Math.floor(total / 3600);
  const m = Math.floor((total % 3600) / 60);
  const sec = String(total % 60).padStart(2, "0");
  return h ? `${h}:${String(m).padStart(2, "0")}:${sec}` : `${m}:${sec}`;
}

function formatModified(modified) {
  // Unix seconds or an ISO string, whichever the server sends.
  const date = isNum(modified) ? new Date(modified * 1000) : typeof modified === "string" ? new Date(modified) : null;
  if (!date || Number.isNaN(date.getTime())) return "";
  return date.toLocaleString([], { dateStyle: "short", timeStyle: "short", hour12: false });
}

function recordingItem(rec) {
  const name = String(rec.name);
  const li = el("li", "recording");
  li.dataset.name = name;
  const info = el("div", "recording-info");
  info.append(el("span", "recording-name", name));
  info.append(el("span", "recording-meta", recordingMeta(rec)));

  const actions = el("div", "recording-actions");
  const replay = el("button", "btn btn-small replay-button", "Replay");
  replay.type = "button";
  replay.addEventListener("click", () => {
    postWithAck($("#recordings .ack"), `Replay ${name}`, "/api/replay", { name });
  });
  const download = el("a", "btn btn-small btn-link download", "Download");
  download.href = `/api/recordings/${encodeURIComponent(name)}`;
  download.setAttribute("download", name);
  actions.append(replay, download);
  li.append(info, actions);
  return li;
}

async function loadRecordings() {
  const list = $("#recordings-list");
  const { status, data, error } = await api("GET", "/api/recordings");
  if (status !== 200 || !Array.isArray(data)) {
    list.replaceChildren(el("li", "empty", `Could not load recordings (${status ? `HTTP ${status}` : error})`));
    delete list.dataset.key;
  } else {
    renderRecordings(data);
  }
  updateControls();
}

/** The recordings list, from GET /api/recordings or the stream (which lists them live: sizes and durations
 * grow, new sessions appear); rebuilt only when something changed. */
function renderRecordings(data) {
  const list = $("#recordings-list");
  const recordings = data.filter((r) => r && r.name != null);
  const key = JSON.stringify(recordings.map((r) => [r.name, r.size, r.duration_s, r.recording]));
  if (list.dataset.key === key) return;
  list.dataset.key = key;
  if (!recordings.length) {
    list.replaceChildren(el("li", "empty", "No recordings yet"));
  } else {
    // Items are kept (only their sizes and durations change), so a click on Replay is never lost to a rebuild.
    const old = new Map(Array.from(list.querySelectorAll("li.recording"), (li) => [li.dataset.name, li]));
    list.replaceChildren(...recordings.map((rec) => {
      const li = old.get(String(rec.name)) || recordingItem(rec);
      setText(li.querySelector(".recording-meta"), recordingMeta(rec));
      li.classList.toggle("is-recording", Boolean(rec.recording));
      return li;
    }));
  }
  updateControls();
}

function recordingMeta(rec) {
  const meta = [formatDuration(rec.duration_s), formatSize(rec.size), formatModified(rec.modified)].filter(Boolean);
  return (rec.recording ? "recording · " : "") + meta.join(" · ");
}

function updateControls() {
  const reason = replayBlocker(auth);
  const buttons = document.querySelectorAll("#recordings-list .replay-button");
  for (const button of buttons) setEnabled(button, reason, "Replay this recording in the 3D view");
  showHint($("#recordings .recordings-hint"), reason && buttons.length ? reason : "");
}

$("#recordings-refresh").addEventListener("click", loadRecordings);
$("#recordings").addEventListener("toggle", () => {
  if ($("#recordings").open) loadRecordings();
});
on(EVENTS.watching, loadRecordings);
on(EVENTS.auth, (detail) => {
  auth = detail.auth;
  updateControls();
});
on(EVENTS.status, (msg) => {
  const modeChanged = msg.mode !== mode;
  mode = msg.mode;
  if (modeChanged) loadRecordings();
  else if (Array.isArray(msg.recordings)) renderRecordings(msg.recordings);
});
