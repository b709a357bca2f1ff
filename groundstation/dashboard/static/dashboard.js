// quadsitl dashboard: server-sent events from /api/stream → uPlot charts and the status panel.
// The server sends decimated rows (display units: m, degrees, N, N·m); this page only keeps the last
// `window` simulated seconds of the selected vehicle and redraws at most every REDRAW_MS, when new rows
// came (the server sends them four times a second, once a second while a run goes faster than 2× real time).
// The x–y map is a plain canvas, seen from above (north up, east right, equal scales): the measured path of
// the window, the reference path, the current setpoint when the horizontal position is controlled (x_ref
// not null) and home at the origin; redrawn with the plots, from the same rows. The stored mission, when
// there is one: its items numbered by seq and joined in order (dotted), the current item ringed.
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
              plan: "#9467bd", current: "#ff7f0e" };

const state = {
  window: 20, fields: [], selected: "", vehicles: {}, data: {}, dirty: false,
  plots: {}, map: null, updates: 0, redraws: 0, lastT: null, mission: null,
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
      title: spec.title, width: box.clientWidth - 8, height: 220,
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
    for (const p of Object.values(state.plots)) p.u.setSize({ width: p.box.clientWidth - 8, height: 220 });
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
    `<span style="color:${MAP.plan}">● mission</span><span style="color:${MAP.current}">◯ current item</span>`;
  const canvas = document.createElement("canvas");
  box.append(title, canvas);
  root.appendChild(box);
  return { box, canvas };
}

// A "nice" grid step (1, 2 or 5 × 10^k) for a span [m] shown over about `lines` grid lines.
function gridStep(span, lines) {
  const raw = span / lines, k = Math.pow(10, Math.floor(Math.log10(raw)));
  return [1, 2, 5, 10].map(m => m * k).find(s => s >= raw);
}

function drawMap() {
  const { box, canvas } = state.map;
  const d = state.data, n = d.t ? d.t.length : 0;
  const ratio = window.devicePixelRatio || 1;
  const W = Math.max(box.clientWidth - 8, 100), H = MAP.height;
  if (canvas.width !== Math.round(W * ratio) || canvas.height !== Math.round(H * ratio)) {
    canvas.width = Math.round(W * ratio); canvas.height = Math.round(H * ratio);
    canvas.style.width = W + "px"; canvas.style.height = H + "px";
  }
  const ctx = canvas.getContext("2d");
  ctx.setTransform(ratio, 0, 0, ratio, 0, 0);
  ctx.clearRect(0, 0, W, H);
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
  const cN = (minN + maxN) / 2, cE = (minE + maxE) / 2;
  const span = Math.max(maxN - minN, maxE - minE, 2) * 1.1;
  const scale = Math.min(W, H) / span; // px per metre
  const px = east => W / 2 + (east - cE) * scale, py = north => H / 2 - (north - cN) * scale;
  // Grid and its spacing.
  const step = gridStep(span, 5);
  ctx.strokeStyle = MAP.grid; ctx.lineWidth = 1; ctx.beginPath();
  for (let e = Math.ceil((cE - W / 2 / scale) / step) * step; e <= cE + W / 2 / scale; e += step) {
    ctx.moveTo(px(e), 0); ctx.lineTo(px(e), H);
  }
  for (let v = Math.ceil((cN - H / 2 / scale) / step) * step; v <= cN + H / 2 / scale; v += step) {
    ctx.moveTo(0, py(v)); ctx.lineTo(W, py(v));
  }
  ctx.stroke();
  ctx.fillStyle = MAP.text; ctx.font = "11px system-ui, sans-serif";
  ctx.fillText(`grid ${step} m`, 6, H - 6);
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
  set("armed", s.armed === undefined ? "–" : s.armed ? "armed" : "disarmed", s.armed ? "warn" : "");
  set("mode", s.mode || "–");
  const m = v.mission;
  set("mission", !m || !m.total ? "none" : `item ${m.current} of ${m.total}, ${m.state_name}`,
      m && m.state === 3 ? "ok" : "");
  set("failsafe", s.failsafe || "–", s.failsafe && s.failsafe !== "none" ? "bad" : "ok");
  set("link", `${v.link.telemetry} (${fmt(v.link.age_s * 1000, 0, " ms")} ago)`, v.link.telemetry === "live" ? "ok" : "bad");
  set("tick_rate", fmt(v.tick_rate, 0, " /s"));
  set("real_time_factor", fmt(v.real_time_factor, 2, "×"));
  set("t", fmt(s.t, 2, " s"));
  set("tick", s.tick === undefined ? "–" : String(s.tick));
}

function onUpdate(msg) {
  state.updates++;
  const select = document.getElementById("vehicle");
  for (const v of msg.vehicles) {
    if (!(v.name in state.vehicles)) {
      if (!Object.keys(state.vehicles).length) select.innerHTML = "";
      const o = document.createElement("option");
      o.value = o.textContent = v.name;
      select.appendChild(o);
    }
    state.vehicles[v.name] = v;
    if (!state.selected) { state.selected = v.name; select.value = v.name; }
    if (v.name === state.selected) {
      if (JSON.stringify(v.mission) !== JSON.stringify(state.mission)) { state.mission = v.mission; state.dirty = true; }
      append(v.rows, v.reset);
      showStatus(v);
    }
  }
}

function connect() {
  const badge = document.getElementById("connection");
  const es = new EventSource("/api/stream");
  es.addEventListener("hello", e => {
    const h = JSON.parse(e.data);
    state.window = h.window;
    state.fields = h.fields;
    state.data = emptyData();
    document.getElementById("window").textContent = h.window;
    document.getElementById("plot-rate").textContent = h.plot_rate;
  });
  es.onmessage = e => onUpdate(JSON.parse(e.data));
  es.onopen = () => { badge.textContent = "connected"; badge.className = "badge ok"; };
  es.onerror = () => { badge.textContent = "reconnecting"; badge.className = "badge bad"; };
  return es;
}

document.getElementById("vehicle").addEventListener("change", e => {
  state.selected = e.target.value;
  state.data = emptyData(); // the next update for it carries its whole window: ask for it afresh
  state.mission = null;
  stream.close();
  stream = connect();
});

makePlots();
let stream = connect();
setInterval(redraw, REDRAW_MS);
