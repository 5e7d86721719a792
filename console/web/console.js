// The pilot's console: polls /state twice a second, shows each value with its age (grey once
// older than STALE_S), and posts commands to /command, which shore sends as `abyss op` does.
// Bound where others reach it, the console asks for the operator's token: the address it printed
// carries it (?token=), and every request here sends it on.
"use strict";
const STALE_S = 3.0;
const $ = (id) => document.getElementById(id);
const TOKEN = new URLSearchParams(location.search).get("token") || "";
const HEADERS = TOKEN ? { "X-Abyss-Token": TOKEN } : {};
const seen = { frame: -1, sonar: -1, viewer: "" };
const TRACK_POINTS = 600; // the vehicle's track on the map: five minutes of telemetry at 2 Hz
const track = [];
let latest = null; // the last state polled
// what the page showed when, for bench/console.py: telemetry samples and commands' answers
window.abyssLog = { telemetry: [], answers: {}, clicks: {} };

function age(ageS) { return ageS === undefined ? "never" : `${ageS.toFixed(1)} s ago`; }
function deg(rad) { return (rad * 180 / Math.PI).toFixed(1); }
function stale(id, part) { $(id).classList.toggle("stale", !part || part.age_s > STALE_S); }
function withToken(path) { return TOKEN ? `${path}${path.includes("?") ? "&" : "?"}token=${encodeURIComponent(TOKEN)}` : path; }
function bars(values) {
  return values.map((v) => `<div class="bar"><span style="left:${50 + Math.min(v, 0) * 50}%;width:${Math.abs(v) * 50}%"></span></div>`).join("");
}

function instruments(t) {
  const rows = t ? [
    ["depth", `${t.depth_m.toFixed(2)} m`], ["heading", `${deg(t.heading_rad)} deg`],
    ["attitude", `roll ${deg(t.roll_rad)} pitch ${deg(t.pitch_rad)} deg`], ["speed", `${t.speed_mps.toFixed(2)} m/s`],
    ["position", t.position_m_world.map((v) => v.toFixed(2)).join(", ") + " m"],
    ["vehicle", t.mode], ["arm", t.arm_mode], ["operator", t.operator_mode],
    ["waypoint", `${t.waypoint_index}/${t.waypoints_total}`],
    ["failsafe", t.failsafe || "off"], ["gripper", `${(t.gripper_opening_m * 1000).toFixed(0)} mm`],
    ["intervention", t.intervention_target ? `${t.intervention_target} ${t.intervention_phase}` : "none"],
    ["joints", t.arm_positions_rad.map(deg).join(" ") + " deg"],
    ["effort", `<span class="age">surge sway heave yaw</span>${bars(t.effort)}`],
  ] : [];
  $("instruments").innerHTML = rows.map(([name, value]) =>
    `<div class="instrument" data-name="${name}"><div class="age">${name}</div><div class="value">${value}</div></div>`).join("")
    + `<div class="age" id="telemetry-age">telemetry ${age(t && t.age_s)}</div>`;
  stale("instruments", t);
  if (t && (track.length === 0 || track[track.length - 1][2] !== t.sim_time_s)) {
    track.push([t.position_m_world[0], t.position_m_world[1], t.sim_time_s]);
    track.splice(0, track.length - TRACK_POINTS);
    window.abyssLog.telemetry.push([t.sim_time_s, Date.now() / 1000, t.age_s]);
  }
}

function mission(m) {
  stale("mission", m);
  if (!m) return;
  $("mission").innerHTML = `<div id="mission-mode">${m.mode}</div>
    <div>waypoint <span id="mission-waypoint">${m.waypoint_index}/${m.waypoints_total}</span>, error ${m.position_error_m.toFixed(2)} m</div>
    <div>interventions ${m.interventions_done}/${m.interventions_total} ${m.intervention_phase}</div>
    <div>done: <span id="mission-done">${m.done}</span></div><div class="age">${age(m.age_s)}</div>`;
}

function parts(objects) {
  const names = objects ? objects.names.filter((n) => n !== "panel") : [];
  const select = $("part");
  if (select.options.length === names.length) return;
  select.innerHTML = names.map((n) => `<option>${n}</option>`).join("");
}

// a relayed image (the camera's frame, the sonar's fan): fetched again only when a new one came
function feed(name, img, part) {
  $(`${name}-age`).textContent = part ? age(part.age_s) : "none yet";
  stale(name === "frame" ? "camera" : "sonar", part);
  if (part && part.count !== seen[name]) {
    seen[name] = part.count;
    $(img).src = withToken(`${name === "frame" ? "frame.jpg" : "sonar.png"}?n=${part.count}`);
  }
}

function lists(state) {
  $("commands").innerHTML = state.commands.map((c) =>
    `<li class="${c.state}" data-id="${c.id}">${c.kind} ${c.text}: ${c.state}${c.reason ? ": " + c.reason : ""}${c.by ? ` <span class="age">by ${c.by}</span>` : ""}</li>`).join("");
  $("alerts").innerHTML = state.alerts.map((a) =>
    `<li>${new Date(a.wall_s * 1000).toLocaleTimeString()} ${a.text}</li>`).join("");
  for (const c of state.commands) {
    if (c.state !== "sent" && window.abyssLog.clicks[c.id] && !window.abyssLog.answers[c.id]) {
      window.abyssLog.answers[c.id] = { clicked_s: window.abyssLog.clicks[c.id], shown_s: Date.now() / 1000,
        sent_s: c.sent_s, answered_s: c.answered_s };
    }
  }
  const others = Object.entries(state.others_teleop).map(([by, n]) => `${by}: ${n} goals`);
  $("others-teleop").textContent = others.length ? `teleop from others: ${others.join(", ")}` : "";
}

// each hop's two directions, as the stations' own link emulators measured them; the round trip is
// the sum of the two directions' median delays
function links(state) {
  const hops = {};
  for (const l of state.links) (hops[l.hop] = hops[l.hop] || []).push(l);
  const num = (v, digits = 0) => (v === undefined ? "-" : v.toFixed(digits));
  $("links").innerHTML = "<tr><th>hop, direction</th><th>profile</th><th>delay p50/p99 [ms]</th><th>queue</th><th>lost</th></tr>"
    + Object.entries(hops).map(([hop, ds]) => {
      const medians = ds.map((d) => d.delay_p50_ms);
      const rtt = ds.length === 2 && medians.every((v) => v !== undefined) ? medians[0] + medians[1] : undefined;
      return `<tr class="hop" data-hop="${hop}"><td><b>${hop}</b></td><td colspan="4">round trip ${num(rtt)} ms</td></tr>`
        + ds.map((d) => `<tr class="${d.age_s > STALE_S * 2 ? "stale" : ""}"><td>${d.direction}</td><td>${d.profile}</td>`
          + `<td>${num(d.delay_p50_ms)}/${num(d.delay_p99_ms)}</td><td>${num(d.in_flight)}</td>`
          + `<td>${num((d.messages_lost || 0) + (d.losses || 0))}</td></tr>`).join("");
    }).join("");
  const p = state.perception;
  $("backlog").textContent = p ? `the scene stream's backlog: ${p.scene_backlog_cells} cells (${age(p.age_s)})` : "";
}

function stations(state) {
  $("stations").innerHTML = Object.entries(state.stations).map(([name, up]) =>
    `<span class="chip ${up ? "up" : "down"}" data-station="${name}">${name}</span>`).join(" ");
  $("by").textContent = `you: ${state.by}`;
}

function viewer(url) {
  if (!url || seen.viewer === url) return;
  seen.viewer = url;
  $("scene-note").textContent = "";
  $("scene").insertAdjacentHTML("beforeend", `<iframe id="viewer" src="${url}"></iframe>`);
}

// The map, seen from above (x east, y north, world): the vehicle and its track, the parts the
// vessel recognised, the waypoints in the text field; a click adds a waypoint there, at the
// vehicle's depth and heading.
const map = {
  scale: 10, cx: 0, cy: 0,
  fit(points) {
    const xs = points.map((p) => p[0]), ys = points.map((p) => p[1]);
    const canvas = $("map"), spanM = Math.max(10, Math.max(...xs) - Math.min(...xs), Math.max(...ys) - Math.min(...ys)) * 1.2;
    this.scale = Math.min(canvas.width, canvas.height) / spanM;
    this.cx = (Math.max(...xs) + Math.min(...xs)) / 2; this.cy = (Math.max(...ys) + Math.min(...ys)) / 2;
  },
  toPixel(x, y) { const c = $("map"); return [c.width / 2 + (x - this.cx) * this.scale, c.height / 2 - (y - this.cy) * this.scale]; },
  toWorld(px, py) { const c = $("map"); return [this.cx + (px - c.width / 2) / this.scale, this.cy - (py - c.height / 2) / this.scale]; },
};
window.abyssMap = map;

function typedWaypoints() {
  return $("waypoints").value.split(";").map((w) => w.split(",").map(Number)).filter((w) => w.length === 4 && w.every(Number.isFinite));
}

function drawMap(state) {
  const canvas = $("map"), g = canvas.getContext("2d"), t = state.telemetry, o = state.objects;
  const waypoints = typedWaypoints();
  const points = [...track, ...waypoints, ...(o ? o.positions_m_world : [])];
  if (points.length === 0) return;
  map.fit(points);
  g.clearRect(0, 0, canvas.width, canvas.height);
  g.strokeStyle = "#1d3a55"; g.fillStyle = "#8fb3d1"; g.font = "11px system-ui";
  const gridM = Math.pow(10, Math.floor(Math.log10(80 / map.scale)));
  const [x0, y1] = map.toWorld(0, 0), [x1, y0] = map.toWorld(canvas.width, canvas.height);
  for (let x = Math.ceil(x0 / gridM) * gridM; x < x1; x += gridM) { const [px] = map.toPixel(x, 0); g.beginPath(); g.moveTo(px, 0); g.lineTo(px, canvas.height); g.stroke(); }
  for (let y = Math.ceil(y0 / gridM) * gridM; y < y1; y += gridM) { const [, py] = map.toPixel(0, y); g.beginPath(); g.moveTo(0, py); g.lineTo(canvas.width, py); g.stroke(); }
  $("map-scale").textContent = `grid ${gridM} m`;
  g.strokeStyle = "#4fc3f7"; g.beginPath();
  track.forEach(([x, y], i) => { const [px, py] = map.toPixel(x, y); if (i) g.lineTo(px, py); else g.moveTo(px, py); });
  g.stroke();
  g.fillStyle = "#ffe082";
  waypoints.forEach(([x, y], i) => { const [px, py] = map.toPixel(x, y); g.fillRect(px - 4, py - 4, 8, 8); g.fillText(`${i + 1}`, px + 6, py - 6); });
  if (o) {
    g.fillStyle = "#ce93d8";
    o.names.forEach((name, i) => { const [px, py] = map.toPixel(o.positions_m_world[i][0], o.positions_m_world[i][1]); g.fillRect(px - 2, py - 2, 4, 4); if (name === "panel") g.fillText(name, px + 4, py + 12); });
  }
  if (t) {
    const [px, py] = map.toPixel(t.position_m_world[0], t.position_m_world[1]), h = t.heading_rad;
    g.fillStyle = "#a5d6a7"; g.beginPath();
    g.moveTo(px + 10 * Math.cos(h), py - 10 * Math.sin(h));
    g.lineTo(px + 6 * Math.cos(h + 2.5), py - 6 * Math.sin(h + 2.5));
    g.lineTo(px + 6 * Math.cos(h - 2.5), py - 6 * Math.sin(h - 2.5)); g.fill();
  }
}

$("map").addEventListener("click", (e) => {
  const t = latest && latest.telemetry;
  if (!t) { $("error").textContent = "no telemetry yet: no depth to put a waypoint at"; return; }
  const rect = $("map").getBoundingClientRect(), k = $("map").width / rect.width;
  const [x, y] = map.toWorld((e.clientX - rect.left) * k, (e.clientY - rect.top) * k);
  const waypoint = [x, y, t.position_m_world[2], t.heading_rad].map((v) => v.toFixed(2)).join(",");
  const typed = $("waypoints").value.trim();
  $("waypoints").value = typed ? `${typed}; ${waypoint}` : waypoint;
  drawMap(latest);
});

async function poll() {
  try {
    const answer = await fetch("state", { cache: "no-store", headers: HEADERS });
    if (answer.status === 401) { $("access").textContent = (await answer.json()).error; return; }
    const state = await answer.json();
    latest = state;
    $("access").textContent = "";
    $("system").textContent = `system ${state.system}`;
    instruments(state.telemetry); mission(state.mission); parts(state.objects);
    feed("frame", "frame", state.frame); feed("sonar", "sonar-fan", state.sonar);
    $("sonar-range").textContent = state.sonar ? `range ${state.sonar.range_max_m} m, ${deg(state.sonar.horizontal_fov_rad)} deg wide` : "";
    lists(state); links(state); stations(state); viewer(state.viewer_url); drawMap(state);
    $("teleop-sent").textContent = state.teleop_sent;
  } catch (e) { $("error").textContent = `the console's server: ${e}`; }
}

async function send(kind, value, amount) {
  $("error").textContent = "";
  const clickedS = Date.now() / 1000;
  const answer = await fetch("command", { method: "POST", headers: HEADERS, body: JSON.stringify({ kind, value, amount }) });
  const body = await answer.json();
  if (!answer.ok) $("error").textContent = body.error; else window.abyssLog.clicks[body.id] = clickedS;
  poll();
}

for (const button of document.querySelectorAll("[data-mode]")) {
  button.addEventListener("click", () => send("mode", button.dataset.mode, ""));
}
// stop here: one waypoint where the vehicle is now, in place of what is left of the mission's
$("stop").addEventListener("click", () => {
  const t = latest && latest.telemetry;
  if (!t) { $("error").textContent = "no telemetry yet: nowhere known to stop at"; return; }
  send("waypoints", [...t.position_m_world, t.heading_rad].map((v) => v.toFixed(3)).join(","), "");
});
$("waypoints-form").addEventListener("submit", (e) => { e.preventDefault(); send("waypoints", $("waypoints").value, ""); });
$("intervene-form").addEventListener("submit", (e) => {
  e.preventDefault();
  const amount = $("amount").value.trim();
  send(["up", "down"].includes(amount) ? "lever" : "valve", $("part").value, amount);
});
// Teleop, as `abyss teleop` does it: goals moved by steps in the vehicle's heading frame, sent
// through shore. A gamepad's sticks move the goal at their deflection times SPEED while the dead-man
// button is held, one step each SEND_S; let go, nothing more is sent and the vehicle stops at the
// goal it was last sent (at most SPEED times SEND_S ahead of where it was heading).
const SPEED_MPS = 0.25, RATE_RADPS = 10 * Math.PI / 180, SEND_S = 0.5, DEADBAND = 0.1, DEADMAN = 4;
const STEP_M = 0.1, STEP_RAD = 5 * Math.PI / 180;
const KEYS = { w: [1, 0, 0, 0, 0, 0], s: [-1, 0, 0, 0, 0, 0], a: [0, 1, 0, 0, 0, 0], d: [0, -1, 0, 0, 0, 0],
  r: [0, 0, 1, 0, 0, 0], f: [0, 0, -1, 0, 0, 0], q: [0, 0, 0, 0, 0, 1], e: [0, 0, 0, 0, 0, -1],
  i: [0, 0, 0, 0, 1, 0], k: [0, 0, 0, 0, -1, 0], u: [0, 0, 0, 1, 0, 0], o: [0, 0, 0, -1, 0, 0] };
let target = "vehicle", lastSendS = performance.now() / 1000, switchHeld = false;

function teleop(step) {
  fetch("teleop", { method: "POST", headers: HEADERS, body: JSON.stringify(
    { target, translation_m: step.slice(0, 3), rotation_rad: step.slice(3) }) })
    .then(async (answer) => { if (!answer.ok) $("error").textContent = (await answer.json()).error; });
}

function switchTarget() { target = target === "vehicle" ? "arm" : "vehicle"; $("teleop-target").textContent = target === "arm" ? "end-effector" : "vehicle"; }

function gamepadTick() {
  const pad = [...(navigator.getGamepads ? navigator.getGamepads() : [])].find((p) => p);
  const nowS = performance.now() / 1000;
  $("gamepad").textContent = pad ? pad.id : window.isSecureContext ? "none" : "none: a browser allows gamepads only over HTTPS or on localhost";
  if (!pad) { lastSendS = nowS; return; }
  if (pad.buttons[0] && pad.buttons[0].pressed !== switchHeld) { switchHeld = pad.buttons[0].pressed; if (switchHeld) switchTarget(); }
  const held = Boolean(pad.buttons[DEADMAN] && pad.buttons[DEADMAN].pressed);
  $("deadman").textContent = held ? "held" : "released";
  const a = [0, 1, 2, 3].map((i) => (Math.abs(pad.axes[i] || 0) > DEADBAND ? pad.axes[i] : 0));
  const dt = nowS - lastSendS;
  if (dt < SEND_S) return;
  lastSendS = nowS;
  if (held && a.some((v) => v !== 0)) {
    teleop([-a[1] * SPEED_MPS * dt, -a[0] * SPEED_MPS * dt, -a[3] * SPEED_MPS * dt, 0, 0, -a[2] * RATE_RADPS * dt]);
  }
}

document.addEventListener("keydown", (e) => {
  if (e.target instanceof HTMLInputElement || e.target instanceof HTMLSelectElement) return;
  if (e.key === "Tab") { e.preventDefault(); switchTarget(); return; }
  const steps = KEYS[e.key];
  if (steps) teleop(steps.map((v, i) => v * (i < 3 ? STEP_M : STEP_RAD)));
});

setInterval(poll, 500);
setInterval(gamepadTick, 100);
poll();
