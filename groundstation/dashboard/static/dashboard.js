// quadsitl dashboard: server-sent events from /api/stream → uPlot charts and the status panel.
// The server sends decimated rows (display units: m, degrees, N, N·m); this page only keeps the last
// `window` simulated seconds of the selected vehicle and redraws at most every REDRAW_MS, when new rows
// came (the server sends them four times a second, once a second while a run goes faster than 2× real time).
// The x–y map is a plain canvas, seen from above (north up, east right, equal scales): the measured path of
// the window, the reference path, the current setpoint when the horizontal position is controlled (x_ref
// not null) and home at the origin; redrawn with the plots, from the same rows. The stored mission, when
// there is one: its items numbered by seq and joined in order (dotted), the current item ringed.
// The fleet view (the default while more than one vehicle is seen, or the launcher says the fleet has more):
// a map of every vehicle in one frame (north, east metres from the origin's home; the server sends each home's
// offset in metres) with its trail and heading, and a table of their status. A row or a marker opens that
// vehicle's plots. The server sends the plot rows of the one vehicle shown (?vehicle=NAME) and, for the fleet,
// only each vehicle's pose and new trail points.
"use strict";

const REDRAW_MS = 250;
const MEASURED = "#1f77b4", REFERENCE = "#d62728";
const PLOTS = [
  { id: "altitude", title: "altitude [m]", series: [["altitude", "altitude", MEASURED], ["altitude_ref", "reference", REFERENCE, true]] },
  { id: "roll", title: "roll φ [deg]", series: [["roll", "roll", MEASURED], ["roll_ref", "reference", REFERENCE, true]] },
  { id: "pitch", title: "pitch θ [deg]", series: [["pitch", "pitch", MEASURED], ["pitch_ref", "reference", REFERENCE, true]] },
  { id: "yaw", title: "yaw ψ [deg]", series: [["yaw", "yaw", MEASURED], ["yaw_ref", "reference", REFERENCE, true]] },
  { id: "errors", title: "tracking errors (reference − measured): altitude [m] left, angles [deg] right",
    series: [["e_altitude", "altitude [m]", "#111", false, "m"], ["e_roll", "roll", "#1f77b4", false, "deg"],
             ["e_pitch", "pitch", "#2ca02c", false, "deg"], ["e_yaw", "yaw", "#ff7f0e", false, "deg"]] },
  { id: "inputs", title: "control inputs: u1 [N] left, u2, u3 [N], u4 [N·m] right",
    series: [["u1", "u1", "#111", false, "thrust"], ["u2", "u2", "#1f77b4", false, "torque"],
             ["u3", "u3", "#2ca02c", false, "torque"], ["u4", "u4", "#ff7f0e", false, "torque"]] },
  { id: "motors", title: "motor forces f1..f4 [N]",
    series: [["f1", "f1", "#1f77b4"], ["f2", "f2", "#2ca02c"], ["f3", "f3", "#ff7f0e"], ["f4", "f4", "#9467bd"]] },
  { id: "position", title: "position x, y [m] (NED)", series: [["x", "x (north)", "#1f77b4"], ["y", "y (east)", "#ff7f0e"]] },
];

const MAP = { height: 320, setpoint: "#d62728", home: "#2ca02c", grid: "#eee", text: "#777",
              plan: "#9467bd", current: "#ff7f0e", fence: "#17becf", excluded: "#d62728", rally: "#8c564b" };

const FLEET = { height: 520, grid: "#eee", text: "#555", minSpan: 4,
                colours: ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
                          "#7f7f7f", "#bcbd22", "#17becf"] };

const state = {
  window: 20, fields: [], selected: "", auto: true, vehicles: {}, data: {}, dirty: false,
  plots: {}, map: null, updates: 0, redraws: 0, lastT: null, mission: null,
  fleet: [], origin: null, trails: {}, fleetDirty: false, fleetRedraws: 0, fleetMarkers: [], fleetDrawMs: [], bytesIn: 0,
};
window.quadsitl = state; // for scripts and tests: what the page holds and how often it redrew

function emptyData() {
  const d = {};
  for (const f of state.fields) d[f] = [];
  return d;
}

function makePlots() {
  const root = document.getElementById("plots");
  const boxes = PLOTS.map(spec => {  // lay out every box first, so that each knows its final width
    const box = document.createElement("div");
    box.className = "plot";
    box.id = "plot-" + spec.id;
    root.appendChild(box);
    return box;
  });
  PLOTS.forEach((spec, k) => {
    const box = boxes[k];
    const scales = { x: { time: false } };
    const axes = [{ label: "t [s]" }];
    const units = [...new Set(spec.series.map(s => s[4]).filter(Boolean))];
    units.forEach((u, i) => {
      scales[u] = {};
      axes.push({ scale: u, side: i === 0 ? 3 : 1, grid: { show: i === 0 }, size: 60 });
    });
    if (!units.length) axes.push({ size: 60 });
    const opts = {
      title: spec.title, width: Math.max(box.clientWidth - 8, 100), height: 220,
      scales, axes, legend: { live: false },
      series: [{ label: "t" }].concat(spec.series.map(([_f, label, stroke, dashed, unit]) => ({
        label, stroke, width: 1.5, dash: dashed ? [6, 4] : undefined, scale: unit || "y",
        points: { show: false },
      }))),
    };
    state.plots[spec.id] = { spec, u: new uPlot(opts, [[], ...spec.series.map(() => [])], box), box };
  });
  state.map = makeMap(root);
  new ResizeObserver(() => {
    for (const p of Object.values(state.plots)) p.u.setSize({ width: Math.max(p.box.clientWidth - 8, 100), height: 220 });
    state.dirty = true; // the map's canvas follows its box at the next redraw
  }).observe(root);
}

function makeMap(root) {
  const box = document.createElement("div");
  box.className = "plot map";
  box.id = "plot-map";
  const title = document.createElement("div");
  title.className = "map-title";
  title.innerHTML = "x–y map [m] from above: x north ↑, y east → " +
    `<span style="color:${MEASURED}">━ path</span><span style="color:${REFERENCE}">┅ reference</span>` +
    `<span style="color:${MAP.setpoint}">⊕ setpoint</span><span style="color:${MAP.home}">■ home</span>` +
    `<span style="color:${MAP.plan}">● mission</span><span style="color:${MAP.current}">◯ current item</span>` +
    `<span style="color:${MAP.fence}">▭ geofence</span><span style="color:${MAP.excluded}">▭ excluded</span>` +
    `<span style="color:${MAP.rally}">▲ rally point</span>`;
  const canvas = document.createElement("canvas");
  box.append(title, canvas);
  root.appendChild(box);
  return { box, canvas };
}

// A "nice" grid step (1, 2 or 5 × 10^k) for a span [m] shown over about `lines` grid lines.
// A map seen from above, north up and east right at equal scales, holding the box [minN, maxN, minE, maxE] [m]
// (at least minSpan metres, times pad): draws its grid (about `lines` lines, its spacing printed) in style's
// colours and returns the projections px(east), py(north), the scale [px per metre] and the grid step [m].
function mapFrame(ctx, W, H, [minN, maxN, minE, maxE], minSpan, pad, lines, style) {
  const cN = (minN + maxN) / 2, cE = (minE + maxE) / 2;
  const span = Math.max(maxN - minN, maxE - minE, minSpan) * pad;
  const scale = Math.min(W, H) / span;
  const px = east => W / 2 + (east - cE) * scale, py = north => H / 2 - (north - cN) * scale;
  const step = gridStep(span, lines);
  ctx.strokeStyle = style.grid; ctx.lineWidth = 1; ctx.beginPath();
  for (let e = Math.ceil((cE - W / 2 / scale) / step) * step; e <= cE + W / 2 / scale; e += step) {
    ctx.moveTo(px(e), 0); ctx.lineTo(px(e), H);
  }
  for (let v = Math.ceil((cN - H / 2 / scale) / step) * step; v <= cN + H / 2 / scale; v += step) {
    ctx.moveTo(0, py(v)); ctx.lineTo(W, py(v));
  }
  ctx.stroke();
  ctx.fillStyle = style.text; ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(`grid ${step} m`, 6, H - 6);
  return { px, py, scale, step };
}

// A map's canvas as wide as its box and `height` px high (CSS pixels, sharp on any pixel ratio), cleared:
// its context and size.
function clearCanvas(box, canvas, height) {
  const ratio = window.devicePixelRatio || 1;
  const W = Math.max(box.clientWidth - 8, 100), H = height;
  if (canvas.width !== Math.round(W * ratio) || canvas.height !== Math.round(H * ratio)) {
    canvas.width = Math.round(W * ratio); canvas.height = Math.round(H * ratio);
    canvas.style.width = W + "px"; canvas.style.height = H + "px";
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, W, H);
  return { ctx, W, H };
}

function gridStep(span, lines) {
  const raw = span / lines, k = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map(m => m * k).find(s => s >= raw);
}

function drawMap() {
  const { box, canvas } = state.map;
  const d = state.data, n = d.t ? d.t.length : 0;
  const { ctx, W, H } = clearCanvas(box, canvas, MAP.height);
  // Bounds over everything drawn (home included), equal scales, at least ±1 m, 10 % margin.
  let minN = 0, maxN = 0, minE = 0, maxE = 0;
  const grow = (north, east) => {
    if (north === null || east === null || north === undefined || east === undefined) return;
    minN = Math.min(minN, north); maxN = Math.max(maxN, north);
    minE = Math.min(minE, east); maxE = Math.max(maxE, east);
  };
  for (let i = 0; i < n; i++) { grow(d.x[i], d.y[i]); grow(d.x_ref[i], d.y_ref[i]); }
  const mission = state.mission;
  const placed = mission ? mission.items.filter(it => it.x !== null && it.y !== null) : [];
  for (const it of placed) grow(it.x, it.y);
  const fence = mission && mission.fence ? mission.fence : [], rally = mission && mission.rally ? mission.rally : [];
  for (const f of fence) {  // a circle's extent, a polygon's vertices
    const r = f.kind >= 3 ? f.size : 0;
    grow(f.x - r, f.y - r); grow(f.x + r, f.y + r);
  }
  for (const p of rally) grow(p.x, p.y);
  const { px, py, scale } = mapFrame(ctx, W, H, [minN, maxN, minE, maxE], 2, 1.1, 5, MAP);
  // The geofence (inclusions, exclusions in red) and the rally points, under everything else.
  ctx.lineWidth = 1.5; ctx.setLineDash([8, 3]);
  for (let i = 0; i < fence.length;) {
    const f = fence[i], inclusion = f.kind === 1 || f.kind === 3;
    ctx.strokeStyle = inclusion ? MAP.fence : MAP.excluded; ctx.beginPath();
    if (f.kind <= 2) {  // a polygon: its vertices follow
      const n = Math.max(1, Math.round(f.size));
      fence.slice(i, i + n).forEach((v, k) => k ? ctx.lineTo(px(v.y), py(v.x)) : ctx.moveTo(px(v.y), py(v.x)));
      ctx.closePath(); i += n;
    } else {
      ctx.arc(px(f.y), py(f.x), f.size * scale, 0, 2 * Math.PI); i += 1;
    }
    ctx.stroke();
  }
  ctx.setLineDash([]);
  ctx.fillStyle = MAP.rally;
  for (const p of rally) {
    ctx.beginPath(); ctx.moveTo(px(p.y), py(p.x) - 7); ctx.lineTo(px(p.y) - 6, py(p.x) + 5);
    ctx.lineTo(px(p.y) + 6, py(p.x) + 5); ctx.closePath(); ctx.fill();
  }
  // The measured path, then the reference dashed over it (where they coincide, both show): null breaks a line.
  const trail = (xs, ys, color, dash, width) => {
    ctx.strokeStyle = color; ctx.lineWidth = width; ctx.setLineDash(dash); ctx.beginPath();
    let pen = false;
    for (let i = 0; i < n; i++) {
      if (xs[i] === null || ys[i] === null) { pen = false; continue; }
      if (pen) ctx.lineTo(px(ys[i]), py(xs[i])); else ctx.moveTo(px(ys[i]), py(xs[i]));
      pen = true;
    }
    ctx.stroke(); ctx.setLineDash([]);
  };
  // The mission under the flight: its legs dotted, its items numbered by seq, the current one ringed.
  let current = null;
  if (placed.length) {
    ctx.strokeStyle = MAP.plan; ctx.lineWidth = 1.2; ctx.setLineDash([2, 4]); ctx.beginPath();
    placed.forEach((it, k) => k ? ctx.lineTo(px(it.y), py(it.x)) : ctx.moveTo(px(it.y), py(it.x)));
    ctx.stroke(); ctx.setLineDash([]);
    ctx.font = "11px system-ui, sans-serif";
    for (const it of placed) {
      ctx.fillStyle = MAP.plan; ctx.beginPath(); ctx.arc(px(it.y), py(it.x), 4, 0, 2 * Math.PI); ctx.fill();
      ctx.fillText(String(it.seq), px(it.y) + 6, py(it.x) - 6);
      if (it.seq === mission.current && mission.state !== 1) current = it;
    }
    if (current) {
      ctx.strokeStyle = MAP.current; ctx.lineWidth = 2.5; ctx.beginPath();
      ctx.arc(px(current.y), py(current.x), 10, 0, 2 * Math.PI); ctx.stroke();
    }
  }
  if (n) { trail(d.x, d.y, MEASURED, [], 1.8); trail(d.x_ref, d.y_ref, REFERENCE, [6, 4], 1.2); }
  // Home: a square at the origin.
  const home = [px(0), py(0)];
  ctx.fillStyle = MAP.home; ctx.fillRect(home[0] - 5, home[1] - 5, 10, 10);
  // The vehicle now, and its setpoint when the horizontal position is controlled.
  let setpoint = null;
  if (n && d.x[n - 1] !== null && d.y[n - 1] !== null) {
    ctx.fillStyle = MEASURED; ctx.beginPath();
    ctx.arc(px(d.y[n - 1]), py(d.x[n - 1]), 4, 0, 2 * Math.PI); ctx.fill();
  }
  if (n && d.x_ref[n - 1] !== null && d.y_ref[n - 1] !== null) {
    setpoint = [d.x_ref[n - 1], d.y_ref[n - 1]];
    const [sx, sy] = [px(setpoint[1]), py(setpoint[0])];
    ctx.strokeStyle = MAP.setpoint; ctx.lineWidth = 2; ctx.beginPath();
    ctx.arc(sx, sy, 7, 0, 2 * Math.PI);
    ctx.moveTo(sx - 10, sy); ctx.lineTo(sx + 10, sy); ctx.moveTo(sx, sy - 10); ctx.lineTo(sx, sy + 10);
    ctx.stroke();
  }
  // For scripts and tests: what the map shows, and where.
  box.dataset.points = n;
  box.dataset.tLast = n ? d.t[n - 1] : "";
  box.dataset.setpoint = setpoint ? setpoint.map(v => v.toFixed(3)).join(",") : "";
  box.dataset.setpointPx = setpoint ? [px(setpoint[1]), py(setpoint[0])].map(v => v.toFixed(1)).join(",") : "";
  box.dataset.homePx = home.map(v => v.toFixed(1)).join(",");
  box.dataset.scale = scale.toFixed(4);
  box.dataset.planItems = placed.length;
  box.dataset.fenceItems = fence.length;
  box.dataset.rallyPx = rally.map(p => [px(p.y), py(p.x)].map(v => v.toFixed(1)).join(",")).join(";");
  box.dataset.current = current ? current.seq : "";
  box.dataset.currentPx = current ? [px(current.y), py(current.x) - 10].map(v => v.toFixed(1)).join(",") : "";
}

function append(rows, reset) {
  if (reset || !state.data.t) state.data = emptyData();
  const d = state.data;
  const n = rows.t ? rows.t.length : 0;
  if (!n) return;
  for (const f of state.fields) for (const v of rows[f]) d[f].push(v);
  const tEnd = d.t[d.t.length - 1];
  let cut = 0;
  while (cut < d.t.length && d.t[cut] < tEnd - state.window) cut++;
  if (cut) for (const f of state.fields) d[f].splice(0, cut);
  state.lastT = tEnd;
  state.dirty = true;
}

function redraw() {
  if (!state.dirty || !state.data.t) return; // nothing new, or no stream yet (a resize before the hello)
  state.dirty = false;
  const d = state.data;
  for (const p of Object.values(state.plots)) {
    p.u.setData([d.t, ...p.spec.series.map(s => d[s[0]])]);
    p.box.dataset.points = d.t.length;
    p.box.dataset.tLast = state.lastT;
  }
  drawMap();
  state.redraws++;
}

function fmt(v, digits, unit) {
  return v === null || v === undefined ? "–" : v.toFixed(digits) + (unit || "");
}

function showStatus(v) {
  const set = (field, text, cls) => {
    const el = document.querySelector(`#status [data-field="${field}"]`);
    el.textContent = text;
    el.className = "v" + (cls ? " " + cls : "");
  };
  const s = v.status || {};
  set("system_id", v.system_id === null || v.system_id === undefined ? "–" : String(v.system_id));
  set("armed", s.armed === undefined ? "–" : s.armed ? "armed" : "disarmed", s.armed ? "warn" : "");
  set("mode", s.mode || "–");
  const m = v.mission;
  set("mission", !m || !m.total ? "none" : `item ${m.current} of ${m.total}, ${m.state_name}`,
      m && m.state === 3 ? "ok" : "");
  set("failsafe", s.failsafe || "–", s.failsafe && s.failsafe !== "none" ? "bad" : "ok");
  const left = s.battery_remaining;  // null: no battery (an ideal supply)
  set("battery", left === null || left === undefined ? "none" :
      `${fmt(left * 100, 0, " %")}, ${fmt(s.battery_v, 2, " V")}, ${fmt(s.battery_a, 1, " A")}`,
      left === null || left === undefined ? "" : left < 0.15 ? "bad" : left < 0.3 ? "warn" : "ok");
  set("link", `${v.link.telemetry} (${fmt(v.link.age_s * 1000, 0, " ms")} ago)`, v.link.telemetry === "live" ? "ok" : "bad");
  set("tick_rate", fmt(v.tick_rate, 0, " /s"));
  set("real_time_factor", fmt(v.real_time_factor, 2, "×"));
  set("t", fmt(s.t, 2, " s"));
  set("tick", s.tick === undefined ? "–" : String(s.tick));
}

function onUpdate(msg) {
  state.updates++;
  const entries = msg.fleet.vehicles;
  state.fleet = entries;
  state.origin = msg.fleet.origin;
  const select = document.getElementById("vehicle");
  for (const e of entries) {
    if (!(e.name in state.vehicles)) {
      const o = document.createElement("option");
      o.value = o.textContent = e.name;
      select.appendChild(o);
    }
    state.vehicles[e.name] = e;
    addTrail(e);
  }
  state.fleetDirty = true;
  if (state.auto) { // the view follows the fleet until someone picks one: one vehicle alone, or the fleet
    const big = entries.some(e => e.fleet_size > 1);
    const want = entries.length === 1 && !big ? entries[0].name : "";
    if (want !== state.selected) { choose(want, true); return; }
  }
  const v = msg.vehicle;
  if (v && v.name === state.selected) {
    if (JSON.stringify(v.mission) !== JSON.stringify(state.mission)) { state.mission = v.mission; state.dirty = true; }
    append(v.rows, v.reset);
    showStatus(v);
  }
}

// ---- the fleet view -------------------------------------------------------------------------------------

function addTrail(e) {
  const tr = e.trail;
  let d = state.trails[e.name];
  if (!d || tr.reset) d = state.trails[e.name] = { t: [], x: [], y: [] };
  for (let i = 0; i < tr.t.length; i++) { d.t.push(tr.t[i]); d.x.push(tr.x[i]); d.y.push(tr.y[i]); }
  const tEnd = d.t.length ? d.t[d.t.length - 1] : 0;
  let cut = 0;
  while (cut < d.t.length && d.t[cut] < tEnd - state.window) cut++;
  if (cut) { d.t.splice(0, cut); d.x.splice(0, cut); d.y.splice(0, cut); }
}

function colourOf(k) { return FLEET.colours[k % FLEET.colours.length]; }

function drawFleet() {
  const t0 = performance.now();
  const box = document.getElementById("fleet-map"), canvas = box.querySelector("canvas");
  const { ctx, W, H } = clearCanvas(box, canvas, FLEET.height);
  // Each vehicle in the common frame: its home's offset (null: not known, drawn from the origin) + local x, y.
  const placed = state.fleet.map((e, k) => {
    const off = e.offset || [0, 0, 0], trail = state.trails[e.name] || { t: [], x: [], y: [] };
    const at = e.pose && e.pose[0] !== null && e.pose[1] !== null ? [off[0] + e.pose[0], off[1] + e.pose[1]] : null;
    return { e, k, off, trail, at, known: !!e.offset };
  });
  let minN = Infinity, maxN = -Infinity, minE = Infinity, maxE = -Infinity;
  const grow = (n, east) => {
    if (n === null || east === null) return;
    if (n < minN) minN = n; if (n > maxN) maxN = n; if (east < minE) minE = east; if (east > maxE) maxE = east;
  };
  for (const p of placed) {
    grow(p.off[0], p.off[1]);
    if (p.at) grow(p.at[0], p.at[1]);
    const tr = p.trail;
    for (let i = 0; i < tr.t.length; i++) if (tr.x[i] !== null && tr.y[i] !== null) grow(p.off[0] + tr.x[i], p.off[1] + tr.y[i]);
  }
  if (minN === Infinity) { minN = maxN = minE = maxE = 0; }
  const { px, py, scale, step } = mapFrame(ctx, W, H, [minN, maxN, minE, maxE], FLEET.minSpan, 1.2, 6, FLEET);
  const markers = [];
  for (const p of placed) {
    const colour = colourOf(p.k), tr = p.trail;
    // the trail (null breaks it), then home, then the vehicle: a triangle along its heading (yaw from north)
    ctx.strokeStyle = colour; ctx.lineWidth = 1.5; ctx.setLineDash(p.known ? [] : [4, 3]); ctx.beginPath();
    let pen = false;
    for (let i = 0; i < tr.t.length; i++) {
      if (tr.x[i] === null || tr.y[i] === null) { pen = false; continue; }
      const X = px(p.off[1] + tr.y[i]), Y = py(p.off[0] + tr.x[i]);
      if (pen) ctx.lineTo(X, Y); else ctx.moveTo(X, Y);
      pen = true;
    }
    ctx.stroke(); ctx.setLineDash([]);
    if (p.known) { ctx.strokeStyle = colour; ctx.lineWidth = 1.5; ctx.strokeRect(px(p.off[1]) - 4, py(p.off[0]) - 4, 8, 8); }
    if (!p.at) continue;
    const X = px(p.at[1]), Y = py(p.at[0]);
    const yaw = (p.e.pose[3] || 0) * Math.PI / 180, dx = Math.sin(yaw), dy = -Math.cos(yaw);
    ctx.beginPath();
    ctx.moveTo(X + 13 * dx, Y + 13 * dy);
    ctx.lineTo(X - 7 * dx + 7 * -dy, Y - 7 * dy + 7 * dx);
    ctx.lineTo(X - 3 * dx, Y - 3 * dy);
    ctx.lineTo(X - 7 * dx - 7 * -dy, Y - 7 * dy - 7 * dx);
    ctx.closePath();
    if (p.known) { ctx.fillStyle = colour; ctx.fill(); ctx.strokeStyle = "#fff"; ctx.lineWidth = 1; ctx.stroke(); }
    else { ctx.fillStyle = "#fff"; ctx.fill(); ctx.strokeStyle = colour; ctx.lineWidth = 2; ctx.setLineDash([3, 2]); ctx.stroke(); ctx.setLineDash([]); }
    const sid = p.e.system_id === null ? "" : ` #${p.e.system_id}`;
    ctx.fillStyle = p.e.link === "live" ? "#222" : "#cf222e"; ctx.font = "12px system-ui, sans-serif";
    ctx.fillText(p.e.name + sid + (p.known ? "" : " (home unknown)"), X + 11, Y - 9);
    markers.push({ name: p.e.name, system_id: p.e.system_id, north: p.at[0], east: p.at[1], yaw: p.e.pose[3],
                   known: p.known, px: X, py: Y });
  }
  state.fleetMarkers = markers;
  box.dataset.markers = JSON.stringify(markers.map(m => ({ ...m, px: +m.px.toFixed(1), py: +m.py.toFixed(1) })));
  box.dataset.scale = scale.toFixed(4);
  box.dataset.step = step;
  const o = state.origin;
  document.getElementById("fleet-origin").textContent =
    o ? `${o.name}'s home (${o.latitude.toFixed(6)}°, ${o.longitude.toFixed(6)}°, ${o.altitude.toFixed(1)} m)` : "no home known yet";
  showFleetTable();
  state.fleetRedraws++;
  state.fleetDrawMs.push(performance.now() - t0);
  if (state.fleetDrawMs.length > 200) state.fleetDrawMs.shift();
}

function cell(tr, k, text, cls) {
  const td = tr.children[k];
  if (td.textContent !== text) td.textContent = text;
  const c = cls || "";
  if (td.className !== c) td.className = c;
}

function showFleetTable() {
  const body = document.querySelector("#fleet-table tbody");
  const waiting = body.querySelector("tr.waiting");
  if (waiting && state.fleet.length) waiting.remove();
  state.fleet.forEach((e, k) => {
    let tr = body.querySelector(`tr[data-name="${CSS.escape(e.name)}"]`);
    if (!tr) {
      tr = document.createElement("tr");
      tr.dataset.name = e.name;
      for (let i = 0; i < 10; i++) tr.appendChild(document.createElement("td"));
      tr.addEventListener("click", () => choose(e.name));
      const sw = document.createElement("span");
      sw.className = "swatch";
      tr.children[0].append(sw, document.createElement("span"));
      tr.children[0].className = "name";
      body.appendChild(tr);
    }
    if (body.children[k] !== tr) body.insertBefore(tr, body.children[k]);
    tr.children[0].firstChild.style.background = colourOf(k);
    if (tr.children[0].lastChild.textContent !== e.name) tr.children[0].lastChild.textContent = e.name;
    cell(tr, 1, e.system_id === null ? "–" : String(e.system_id));
    cell(tr, 2, e.mode || "–");
    cell(tr, 3, e.armed === null ? "–" : e.armed ? "armed" : "disarmed", e.armed ? "warn" : "");
    cell(tr, 4, e.failsafe || "–", e.failsafe && e.failsafe !== "none" ? "bad" : "ok");
    cell(tr, 5, `${e.link} (${fmt(e.age_s * 1000, 0, " ms")})`, e.link === "live" ? "ok" : "bad");
    cell(tr, 6, fmt(e.tick_rate, 0, " /s"));
    cell(tr, 7, fmt(e.real_time_factor, 2, "×"));
    cell(tr, 8, e.pose ? fmt(e.pose[2], 2, " m") : "–");
    cell(tr, 9, e.offset ? `${e.offset[0].toFixed(1)}, ${e.offset[1].toFixed(1)} m` : e.home_note, e.offset ? "home" : "home bad");
  });
}

function clickMap(ev) {
  const rect = ev.target.getBoundingClientRect(), x = ev.clientX - rect.left, y = ev.clientY - rect.top;
  let best = null, bestD = 20;
  for (const m of state.fleetMarkers) {
    const d = Math.hypot(m.px - x, m.py - y);
    if (d < bestD) { best = m; bestD = d; }
  }
  if (best) choose(best.name);
}

// ---- choosing what to show ------------------------------------------------------------------------------

function choose(name, auto) {
  state.auto = !!auto;
  state.selected = name;
  document.getElementById("vehicle").value = name;
  document.getElementById("fleet-view").hidden = !!name;
  document.getElementById("single-view").hidden = !name;
  document.getElementById("fleet-tab").classList.toggle("active", !name);
  state.data = emptyData(); // the next update for it carries its whole window: ask for it afresh
  state.mission = null;
  state.lastT = null;
  state.dirty = state.fleetDirty = true;
  if (stream) stream.close();
  stream = connect();
}

function redrawAny() {
  if (state.selected) redraw();
  else if (state.fleetDirty) { state.fleetDirty = false; drawFleet(); }
}

function connect() {
  const badge = document.getElementById("connection");
  const es = new EventSource("/api/stream" + (state.selected ? "?vehicle=" + encodeURIComponent(state.selected) : ""));
  es.addEventListener("hello", e => {
    const h = JSON.parse(e.data);
    state.window = h.window;
    state.fields = h.fields;
    state.data = emptyData();
    document.getElementById("window").textContent = h.window;
    document.getElementById("plot-rate").textContent = h.plot_rate;
  });
  es.onmessage = e => { state.bytesIn += e.data.length; onUpdate(JSON.parse(e.data)); };
  es.onopen = () => { badge.textContent = "connected"; badge.className = "badge ok"; };
  es.onerror = () => { badge.textContent = "reconnecting"; badge.className = "badge bad"; };
  return es;
}

document.getElementById("vehicle").addEventListener("change", e => choose(e.target.value));
document.getElementById("fleet-tab").addEventListener("click", () => choose(""));
document.querySelector("#fleet-map canvas").addEventListener("click", clickMap);
new ResizeObserver(() => { state.fleetDirty = true; }).observe(document.getElementById("fleet-view"));

let stream = null;
state.choose = choose; // for scripts and tests: show one vehicle (its name) or the fleet ("")
makePlots();
choose("", true);
setInterval(redrawAny, REDRAW_MS);
