// The pilot's console: polls /state twice a second, shows each value with its age (grey once
// older than STALE_S), and posts commands to /command, which shore sends as `abyss op` does.
"use strict";
const STALE_S = 3.0;
const $ = (id) => document.getElementById(id);
let frameCount = -1;

function age(ageS) { return ageS === undefined ? "never" : `${ageS.toFixed(1)} s ago`; }
function deg(rad) { return (rad * 180 / Math.PI).toFixed(1); }

function instruments(t) {
  const rows = t ? [
    ["depth", `${t.depth_m.toFixed(2)} m`], ["heading", `${deg(t.heading_rad)} deg`],
    ["position", t.position_m_world.map((v) => v.toFixed(2)).join(", ") + " m"],
    ["vehicle", t.mode], ["arm", t.arm_mode], ["operator", t.operator_mode],
    ["waypoint", `${t.waypoint_index}/${t.waypoints_total}`],
    ["failsafe", t.failsafe || "off"], ["gripper", `${(t.gripper_opening_m * 1000).toFixed(0)} mm`],
    ["intervention", t.intervention_target ? `${t.intervention_target} ${t.intervention_phase}` : "none"],
    ["joints", t.arm_positions_rad.map(deg).join(" ") + " deg"],
  ] : [];
  $("instruments").innerHTML = rows.map(([name, value]) =>
    `<div class="instrument" data-name="${name}"><div class="age">${name}</div><div class="value">${value}</div></div>`).join("")
    + `<div class="age" id="telemetry-age">telemetry ${age(t && t.age_s)}</div>`;
  $("instruments").classList.toggle("stale", !t || t.age_s > STALE_S);
}

function mission(m) {
  $("mission").classList.toggle("stale", !m || m.age_s > STALE_S);
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

function frame(f) {
  $("frame-age").textContent = f ? age(f.age_s) : "none yet";
  $("camera").classList.toggle("stale", !f || f.age_s > STALE_S);
  if (f && f.count !== frameCount) { frameCount = f.count; $("frame").src = `frame.jpg?n=${f.count}`; }
}

function lists(state) {
  $("commands").innerHTML = state.commands.map((c) =>
    `<li class="${c.state}" data-id="${c.id}">${c.kind} ${c.text}: ${c.state}${c.reason ? ": " + c.reason : ""}</li>`).join("");
  $("alerts").innerHTML = state.alerts.map((a) =>
    `<li>${new Date(a.wall_s * 1000).toLocaleTimeString()} ${a.text}</li>`).join("");
}

async function poll() {
  try {
    const state = await (await fetch("state", { cache: "no-store" })).json();
    $("system").textContent = `system ${state.system}`;
    instruments(state.telemetry); mission(state.mission); parts(state.objects); frame(state.frame); lists(state);
    $("teleop-sent").textContent = state.teleop_sent;
  } catch (e) { $("error").textContent = `the console's server: ${e}`; }
}

async function send(kind, value, amount) {
  $("error").textContent = "";
  const answer = await fetch("command", { method: "POST", body: JSON.stringify({ kind, value, amount }) });
  if (!answer.ok) $("error").textContent = (await answer.json()).error;
  poll();
}

for (const button of document.querySelectorAll("[data-mode]")) {
  button.addEventListener("click", () => send("mode", button.dataset.mode, ""));
}
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
  fetch("teleop", { method: "POST", body: JSON.stringify(
    { target, translation_m: step.slice(0, 3), rotation_rad: step.slice(3) }) })
    .then(async (answer) => { if (!answer.ok) $("error").textContent = (await answer.json()).error; });
}

function switchTarget() { target = target === "vehicle" ? "arm" : "vehicle"; $("teleop-target").textContent = target === "arm" ? "end-effector" : "vehicle"; }

function gamepadTick() {
  const pad = [...(navigator.getGamepads ? navigator.getGamepads() : [])].find((p) => p);
  const nowS = performance.now() / 1000;
  $("gamepad").textContent = pad ? pad.id : "none";
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
