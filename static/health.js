// The station's own health: a link down, a stalled link thread, a recording that fails, vehicles turned
// away, a vehicle far from the scene. Said at the top of the panel, since every number below may be stale,
// incomplete or drawn in the wrong place because of it.

import { $, api, el } from "./common.js";

const HEALTH_PERIOD_MS = 5000;
const ELSEWHERE_SHOWN_MS = 60000;  // how long messages dropped as from elsewhere stay said after the last one
const elsewhere = new Map();  // sysid -> { messages: dropped so far, at: when that count last grew (page clock) }

function healthProblems(health) {
  const problems = [];
  for (const far of (health && health.far_from_scene) || []) {
    problems.push(`vehicle ${far.sysid} is ${far.km.toLocaleString("en")} km from the scene: ` +
                  "is the station's datum where it flies? (--datum, or the scene's)");
  }
  const link = health && health.link;
  if (!link) return problems;
  for (const port of link.links || []) {
    if (!port.up) problems.push(`MAVLink ${port.url} is down${port.error ? `: ${port.error}` : ""}`);
  }
  if (link.thread !== "ok") problems.push("the MAVLink thread has stalled: nothing new is received");
  if (link.recording_error) problems.push(`recording failed: ${link.recording_error}`);
  const held = link.vehicles || {};
  if (held.refused) problems.push(`${held.refused} new vehicles turned away: ${held.held} held, the most allowed`);
  for (const refused of (link.signing && link.signing.refused) || []) {
    problems.push(`system ${refused.sysid}: ${refused.messages} messages dropped, not signed with the key`);
  }
  for (const dropped of link.from_elsewhere || []) {
    const seen = elsewhere.get(dropped.sysid);
    if (!seen || dropped.messages > seen.messages) elsewhere.set(dropped.sysid, { messages: dropped.messages, at: Date.now() });
    if (Date.now() - elsewhere.get(dropped.sysid).at < ELSEWHERE_SHOWN_MS) {
      problems.push(`vehicle ${dropped.sysid}: ${dropped.messages} messages in its autopilot's name dropped, from ` +
                    "elsewhere than its heartbeat (a second link to it, or someone sending as it)");
    }
  }
  return problems;
}

async function checkHealth() {
  const { status, data } = await api("GET", "/api/health");
  const banner = $("#health-banner");
  const problems = status === 200 ? healthProblems(data) : [];
  banner.hidden = problems.length === 0;
  banner.replaceChildren(...problems.map((text) => el("li", "", text)));
  banner.dataset.checked = String(status);  // when it last looked, and what the station answered
}

window.addEventListener("DOMContentLoaded", () => {
  checkHealth();
  setInterval(checkHealth, HEALTH_PERIOD_MS);
});
