// The daemon's live view: the queue (polled), the followed campaign's event stream (measurements,
// states), the gantry pose and a BRDF slice that fills in as measurements arrive. No build step.
"use strict";
const $ = (id) => document.getElementById(id);
const state = { follow: null, source: null, auth: false, steps: 0, done: 0, dark: null, ref: null, points: [],
                pose: null, thetaRefCos: 1, gantry: null, refFr: null };
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
      `<td>${escapeHtml(breakable(c.material || c.sample || ""))}</td><td>${escapeHtml(breakable(c.grid))}</td>` +
      `<td>${c.steps_done}/${c.steps} (${pct} %)</td><td>${eta}</td></tr>`;
  });
  $("queue").querySelector("tbody").innerHTML = rows.join("") ||
    '<tr><td colspan="6">no campaigns: submit one with <code>gonio submit</code></td></tr>';
}
function escapeHtml(s) { return String(s).replace(/[&<>"']/g, (c) => `&#${c.charCodeAt(0)};`); }
// A MATERIAL or GRID string may break after each comma, never inside a key=value (rho_s=0. / 8).
function breakable(s) { return String(s).replace(/,/g, ",\u200b"); }

function pick(list) {
  if (list.running) return list.running;
  const open = list.campaigns.filter((c) => !TERMINAL.has(c.state));
  if (open.length) return open[0].id;
  return list.campaigns.length ? list.campaigns[list.campaigns.length - 1].id : null;
}

function setBar(done, steps) {
  // the event stream replays a finished campaign's readings from the start: the bar never goes back
  state.done = Math.max(state.done, done);
  $("bar-fill").style.width = `${(100 * state.done / Math.max(steps, 1)).toFixed(1)}%`;
}

function renderRunning(c) {
  $("run-title").textContent = c ? "Campaign" : "No campaign yet";
  $("run-id").textContent = c ? c.id : "";
  $("run-state").textContent = c ? c.state : "";
  $("run-what").textContent = c ? breakable(`${c.material || c.sample} · ${c.grid} · seed ${c.seed} · ${c.gantry}`) : "";
  if (c) {
    setBar(c.steps_done, c.steps);
    const finished = TERMINAL.has(c.state);
    $("run-progress").textContent = `${c.steps_done}/${c.steps} steps (${(100 * c.progress).toFixed(1)} %) · ` +
      `gantry time ${hms(c.campaign_s)}` + (finished ? "" :
      ` · ETA ${c.eta_wall_s !== null ? hms(c.eta_wall_s) + " wall, " : ""}${hms(c.eta_gantry_s)} of gantry time`) +
      (c.latched_fault ? ` · FAULT: ${c.latched_fault}` : "");
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
    if (g.detector && g.detector.reference_fr && !state.refFr) { state.refFr = g.detector.reference_fr; drawSlice(); }
    if (!g.owner || !state.pose) state.pose = g.angles;
    drawSketch();
  } catch (e) {
    $("conn").textContent = "daemon unreachable";
  }
}

function follow(id) {
  if (state.source) state.source.close();
  Object.assign(state, { follow: id, source: null, dark: null, ref: null, points: [], steps: 0, done: 0 });
  drawSlice();
  if (!id) return;
  const es = new EventSource(`/campaigns/${id}/events`);
  state.source = es;
  es.onopen = () => { $("conn").textContent = "live"; };
  es.onerror = () => { $("conn").textContent = "reconnecting…"; };
  es.addEventListener("measurement", (ev) => onMeasurement(JSON.parse(ev.data)));
  // The stream replays a campaign's states from the start: done or aborted is final, and a replayed
  // 'running' must not show a finished campaign running again.
  es.addEventListener("state", (ev) => {
    const d = JSON.parse(ev.data);
    if (!TERMINAL.has($("run-state").textContent)) $("run-state").textContent = d.state;
  });
  es.addEventListener("fault", (ev) => say("fault: " + JSON.parse(ev.data).message));
  es.addEventListener("end", (ev) => { $("conn").textContent = "finished: " + JSON.parse(ev.data).state; es.close(); refresh(); });
}

function rates(m) { return m.signal.map((s) => s / m.exposure_s); }

function onMeasurement(m) {
  state.steps = m.steps;
  setBar(m.done, m.steps);
  if (m.kind === "dark") { state.dark = rates(m); return; }
  state.pose = { theta_i_deg: m.theta_i_deg, phi_i_deg: m.phi_i_deg, theta_o_deg: m.theta_o_deg, phi_o_deg: m.phi_o_deg };
  if (m.kind === "reference") {
    state.ref = rates(m);
    state.thetaRefCos = Math.cos(m.theta_i_deg * Math.PI / 180);
  } else if (state.ref !== null) {
    const s = rates(m), d = state.dark || s.map(() => 0), rho = state.refFr || s.map(() => 1);
    const ci = Math.cos(m.theta_i_deg * Math.PI / 180);
    // f_r in sr^-1 per channel, as the calibration has it: rho_ref/pi * (S - D) / (R - D) * cos(theta_ref) / cos(theta_i);
    // the slice shows the mean over the channels
    const fc = s.map((x, c) => rho[c] / Math.PI * (x - d[c]) / (state.ref[c] - d[c]) * state.thetaRefCos / Math.max(ci, 1e-3));
    const f = fc.reduce((a, b) => a + b, 0) / fc.length;
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
  const labels = [];
  // Each arm's label beside its end, the light's always to its left and the detector's to its right: at
  // 0° (both arms up) they sat on top of each other.
  const arm = (theta, s, colour, label, toLeft) => {
    const a = theta * Math.PI / 180, x = cx + s * R * Math.sin(a), y = cy - R * Math.cos(a);
    g.strokeStyle = colour; g.lineWidth = 3; g.beginPath(); g.moveTo(cx, cy); g.lineTo(x, y); g.stroke();
    g.fillStyle = colour; g.beginPath(); g.arc(x, y, 8, 0, 2 * Math.PI); g.fill();
    const w = g.measureText(label).width, lx = toLeft ? x - 12 - w : x + 12, ly = y - 4;
    g.textAlign = "left";
    g.fillText(label, lx, ly);
    labels.push({ text: label, x: lx, y: ly - 12, w, h: 14 });
  };
  g.font = "12px system-ui";
  arm(p.theta_i_deg, -1, "#e0a000", "light", true);
  arm(p.theta_o_deg, side, "#3b7ddd", "detector", false);
  c.dataset.labels = JSON.stringify(labels);
  $("pose").textContent = `θi ${p.theta_i_deg.toFixed(1)}°  φi ${p.phi_i_deg.toFixed(1)}°  ` +
    `θo ${p.theta_o_deg.toFixed(1)}°  φo ${p.phi_o_deg.toFixed(1)}°` +
    (state.gantry && state.gantry.moving ? "  (moving)" : "");
}

const SLICE_COLOURS = (ti) => `hsl(${Math.round(ti * 3)}, 70%, 45%)`;

function drawSlice() {
  const c = $("slice"), g = c.getContext("2d"), W = c.width, H = c.height;
  g.clearRect(0, 0, W, H);
  const L = 56, B = H - 58, T = 10, Rr = W - 10;
  const fmax = Math.max(...state.points.map((q) => q.f), 0) || 1;
  const top = 1.1 * fmax;   // head room: the largest values are not drawn on the frame
  const X = (deg) => L + (deg + 90) / 180 * (Rr - L), Y = (f) => B - Math.max(f, 0) / top * (B - T);
  g.strokeStyle = "#8893a8"; g.lineWidth = 1;
  g.beginPath(); g.moveTo(L, T); g.lineTo(L, B); g.lineTo(Rr, B); g.stroke();
  g.fillStyle = "#1d2330"; g.font = "11px system-ui";
  // y: zero, half and the largest value, in sr^-1
  g.textAlign = "right";
  for (const v of [0, fmax / 2, fmax]) {
    g.fillText(v === 0 ? "0" : v.toPrecision(2), L - 4, Y(v) + 4);
    g.strokeStyle = "#e4e7ee"; g.beginPath(); g.moveTo(L + 1, Y(v)); g.lineTo(Rr, Y(v)); g.stroke();
  }
  g.save(); g.translate(10, (T + B) / 2); g.rotate(-Math.PI / 2); g.textAlign = "center";
  g.fillText("f_r (sr⁻¹)", 0, 0); g.restore();
  // x: signed θo in the plane of incidence
  g.textAlign = "center";
  for (const deg of [-90, -45, 0, 45, 90]) g.fillText(`${deg}°`, X(deg), B + 13);
  g.fillText("θo: ← light side | specular side →", (L + Rr) / 2, B + 27);
  g.textAlign = "left";
  $("slice-label").textContent = `(${state.points.length} in-plane samples; f_r in sr⁻¹${state.refFr ? "" : " once the standard's reflectance is known"})`;
  const incidences = [...new Set(state.points.map((q) => q.ti))].sort((a, b) => a - b);
  for (const q of state.points) {
    g.fillStyle = SLICE_COLOURS(q.ti);
    g.beginPath(); g.arc(X(q.x), Y(q.f), 2.5, 0, 2 * Math.PI); g.fill();
  }
  // legend, below the axis: one dot per incidence drawn (at most 5)
  const every = Math.ceil(incidences.length / 5);
  incidences.filter((_, k) => k % every === 0).forEach((ti, k) => {
    const x = L + k * 58, y = B + 45;
    g.fillStyle = SLICE_COLOURS(ti); g.beginPath(); g.arc(x, y - 4, 3.5, 0, 2 * Math.PI); g.fill();
    g.fillStyle = "#1d2330"; g.fillText(`θi ${Math.round(ti)}°`, x + 6, y);
  });
  c.dataset.fmax = String(state.points.length ? fmax : 0);
  c.dataset.incidences = String(incidences.length);
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
