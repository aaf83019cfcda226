// The daemon's live view: the queue (polled), the followed campaign's event stream (measurements,
// states), the gantry pose and a BRDF slice that fills in as measurements arrive. No build step.
"use strict";
const $ = (id) => document.getElementById(id);
const state = { follow: null, source: null, auth: false, steps: 0, dark: null, ref: null, points: [],
                pose: null, thetaRefCos: 1, gantry: null };
const TERMINAL = new Set(["done", "aborted"]);

function hms(s) {
  if (s === null || s === undefined || !isFinite(s)) return "–";
  s = Math.round(s);
  return `${Math.floor(s / 3600)}:${String(Math.floor(s % 3600 / 60)).padStart(2, "0")}:${String(s % 60).padStart(2, "0")}`;
}
function token() { return $("token").value.trim(); }
function canWrite() { return !state.auth || token().length > 0; }
function say(text) { $("message").textContent = text || ""; }

async function post(path) {
  const headers = {};
  if (token()) headers["Authorization"] = "Bearer " + token();
  const r = await fetch(path, { method: "POST", headers });
  const body = await r.json().catch(() => ({}));
  if (!r.ok) say(`${r.status}: ${typeof body.detail === "string" ? body.detail : JSON.stringify(body.detail)}`);
  else say(body.message || "");
  refresh();
}

function renderQueue(list) {
  const rows = list.campaigns.map((c) => {
    const pct = (100 * c.progress).toFixed(1);
    const eta = c.state === "running" ? hms(c.eta_wall_s) + " (gantry " + hms(c.eta_gantry_s) + ")" : "";
    return `<tr data-id="${c.id}"><td>${c.id}</td><td><span class="badge">${c.state}</span></td>` +
      `<td>${escapeHtml(c.material || c.sample || "")}</td><td>${escapeHtml(c.grid)}</td>` +
      `<td>${c.steps_done}/${c.steps} (${pct} %)</td><td>${eta}</td></tr>`;
  });
  $("queue").querySelector("tbody").innerHTML = rows.join("") ||
    '<tr><td colspan="6">no campaigns: submit one with <code>gonio submit</code></td></tr>';
}
function escapeHtml(s) { return String(s).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`); }

function pick(list) {
  if (list.running) return list.running;
  const open = list.campaigns.filter((c) => !TERMINAL.has(c.state));
  if (open.length) return open[0].id;
  return list.campaigns.length ? list.campaigns[list.campaigns.length - 1].id : null;
}

function renderRunning(c) {
  $("run-id").textContent = c ? c.id : "none";
  $("run-state").textContent = c ? c.state : "";
  $("run-what").textContent = c ? `${c.material || c.sample} · ${c.grid} · seed ${c.seed} · ${c.gantry}` : "";
  if (c) {
    $("bar-fill").style.width = `${(100 * c.progress).toFixed(1)}%`;
    $("run-progress").textContent = `${c.steps_done}/${c.steps} steps (${(100 * c.progress).toFixed(1)} %) · ` +
      `gantry time ${hms(c.campaign_s)} · ETA ${c.eta_wall_s !== null ? hms(c.eta_wall_s) + " wall, " : ""}` +
      `${hms(c.eta_gantry_s)} of gantry time` + (c.latched_fault ? ` · FAULT: ${c.latched_fault}` : "");
  }
  const w = canWrite();
  $("pause").disabled = !c || !w || TERMINAL.has(c.state);
  $("resume").disabled = !c || !w || TERMINAL.has(c.state);
  // HALT is never disabled: from the rig (loopback) the daemon takes it without a token, and an
  // emergency stop must not wait for the page to agree.
}

async function refresh() {
  try {
    const list = await (await fetch("/campaigns")).json();
    renderQueue(list);
    const id = pick(list);
    if (id !== state.follow) follow(id);
    renderRunning(list.campaigns.find((c) => c.id === id));
    const g = await (await fetch("/gantry")).json();
    state.gantry = g;
    if (!g.owner || !state.pose) state.pose = g.angles;
    drawSketch();
  } catch (e) {
    $("conn").textContent = "daemon unreachable";
  }
}

function follow(id) {
  if (state.source) state.source.close();
  Object.assign(state, { follow: id, source: null, dark: null, ref: null, points: [], steps: 0 });
  drawSlice();
  if (!id) return;
  const es = new EventSource(`/campaigns/${id}/events`);
  state.source = es;
  es.onopen = () => { $("conn").textContent = "live"; };
  es.onerror = () => { $("conn").textContent = "reconnecting…"; };
  es.addEventListener("measurement", (ev) => onMeasurement(JSON.parse(ev.data)));
  es.addEventListener("state", (ev) => { const d = JSON.parse(ev.data); $("run-state").textContent = d.state; });
  es.addEventListener("fault", (ev) => say("fault: " + JSON.parse(ev.data).message));
  es.addEventListener("end", (ev) => { $("conn").textContent = "finished: " + JSON.parse(ev.data).state; es.close(); refresh(); });
}

function rate(m) {
  const s = m.signal.reduce((a, b) => a + b, 0) / m.signal.length;
  return s / m.exposure_s;
}

function onMeasurement(m) {
  state.steps = m.steps;
  $("bar-fill").style.width = `${(100 * m.done / m.steps).toFixed(1)}%`;
  if (m.kind === "dark") { state.dark = rate(m); return; }
  state.pose = { theta_i_deg: m.theta_i_deg, phi_i_deg: m.phi_i_deg, theta_o_deg: m.theta_o_deg, phi_o_deg: m.phi_o_deg };
  if (m.kind === "reference") {
    state.ref = rate(m);
    state.thetaRefCos = Math.cos(m.theta_i_deg * Math.PI / 180);
  } else if (state.ref !== null) {
    const d = state.dark || 0;
    const ci = Math.cos(m.theta_i_deg * Math.PI / 180);
    // f_r in units of the white standard's rho/pi: (S - D) / (R - D) * cos(theta_ref) / cos(theta_i)
    const f = (rate(m) - d) / (state.ref - d) * state.thetaRefCos / Math.max(ci, 1e-3);
    let dphi = ((m.phi_o_deg - m.phi_i_deg) % 360 + 360) % 360;
    if (Math.abs(dphi - 180) < 1) state.points.push({ ti: m.theta_i_deg, x: m.theta_o_deg, f });
    else if (dphi < 1 || dphi > 359) state.points.push({ ti: m.theta_i_deg, x: -m.theta_o_deg, f });
  }
  drawSketch();
  drawSlice();
}

function drawSketch() {
  const c = $("sketch"), g = c.getContext("2d"), W = c.width, H = c.height;
  g.clearRect(0, 0, W, H);
  const cx = W / 2, cy = H - 30, R = Math.min(W / 2 - 20, H - 50);
  g.strokeStyle = "#b8c0d0"; g.lineWidth = 1;
  g.beginPath(); g.arc(cx, cy, R, Math.PI, 2 * Math.PI); g.stroke();
  g.fillStyle = "#6a7388"; g.fillRect(cx - 30, cy, 60, 6);            // the sample
  const p = state.pose;
  if (!p || p.theta_i_deg === null || !isFinite(p.theta_i_deg)) return;
  const dphi = ((p.phi_o_deg - p.phi_i_deg) % 360 + 360) % 360;
  const side = Math.cos(dphi * Math.PI / 180) < 0 ? 1 : -1;         // detector opposite the light, or beside it
  const arm = (theta, s, colour, label) => {
    const a = theta * Math.PI / 180, x = cx + s * R * Math.sin(a), y = cy - R * Math.cos(a);
    g.strokeStyle = colour; g.lineWidth = 3; g.beginPath(); g.moveTo(cx, cy); g.lineTo(x, y); g.stroke();
    g.fillStyle = colour; g.beginPath(); g.arc(x, y, 8, 0, 2 * Math.PI); g.fill();
    g.textAlign = s > 0 ? "right" : "left";
    g.fillText(label, x + (s > 0 ? -12 : 12), y - 10);
    g.textAlign = "left";
  };
  g.font = "12px system-ui";
  arm(p.theta_i_deg, -1, "#e0a000", "light");
  arm(p.theta_o_deg, side, "#3b7ddd", "detector");
  $("pose").textContent = `θi ${p.theta_i_deg.toFixed(1)}°  φi ${p.phi_i_deg.toFixed(1)}°  ` +
    `θo ${p.theta_o_deg.toFixed(1)}°  φo ${p.phi_o_deg.toFixed(1)}°` +
    (state.gantry && state.gantry.moving ? "  (moving)" : "");
}

function drawSlice() {
  const c = $("slice"), g = c.getContext("2d"), W = c.width, H = c.height;
  g.clearRect(0, 0, W, H);
  const L = 40, B = H - 25, T = 10, Rr = W - 10;
  g.strokeStyle = "#8893a8"; g.lineWidth = 1;
  g.beginPath(); g.moveTo(L, T); g.lineTo(L, B); g.lineTo(Rr, B); g.stroke();
  g.fillStyle = "#1d2330"; g.font = "11px system-ui";
  g.fillText("−90°", L - 10, B + 14); g.fillText("θo in plane", (L + Rr) / 2 - 30, B + 14); g.fillText("90°", Rr - 20, B + 14);
  $("slice-label").textContent = `(${state.points.length} in-plane samples; f_r in units of ρ_ref/π)`;
  if (!state.points.length) return;
  const fmax = Math.max(...state.points.map((q) => q.f), 1e-9);
  g.fillText(fmax.toPrecision(3), 2, T + 8);
  for (const q of state.points) {
    const x = L + (q.x + 90) / 180 * (Rr - L), y = B - Math.max(q.f, 0) / fmax * (B - T);
    g.fillStyle = `hsl(${Math.round(q.ti * 3)}, 70%, 45%)`;
    g.beginPath(); g.arc(x, y, 2.5, 0, 2 * Math.PI); g.fill();
  }
}

async function start() {
  $("token").value = sessionStorage.getItem("gonio-token") || "";
  $("token").addEventListener("input", () => { sessionStorage.setItem("gonio-token", token()); refresh(); });
  $("pause").onclick = () => state.follow && post(`/campaigns/${state.follow}/pause`);
  $("resume").onclick = () => state.follow && post(`/campaigns/${state.follow}/resume`);
  $("halt").onclick = () => post("/gantry/halt");
  try {
    const h = await (await fetch("/health")).json();
    state.auth = h.auth;
    $("gantry-name").textContent = "· " + h.gantry + " · " + h.version;
  } catch (e) { /* refresh() says so */ }
  drawSlice();
  await refresh();
  setInterval(refresh, 1500);
}
start();
