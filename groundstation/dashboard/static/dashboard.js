// quadsitl dashboard: server-sent events from /api/stream → uPlot charts and the status panel.
// The server sends decimated rows (display units: m, degrees, N, N·m); this page only keeps the last
// `window` simulated seconds of the selected vehicle and redraws at most every REDRAW_MS, when new rows
// came (the server sends them four times a second, once a second while a run goes faster than 2× real time).
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

const state = {
  window: 20, fields: [], selected: "", vehicles: {}, data: {}, dirty: false,
  plots: {}, updates: 0, redraws: 0, lastT: null,
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
  new ResizeObserver(() => {
    for (const p of Object.values(state.plots)) p.u.setSize({ width: p.box.clientWidth - 8, height: 220 });
  }).observe(root);
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
  if (!state.dirty) return;
  state.dirty = false;
  const d = state.data;
  for (const p of Object.values(state.plots)) {
    p.u.setData([d.t, ...p.spec.series.map(s => d[s[0]])]);
    p.box.dataset.points = d.t.length;
    p.box.dataset.tLast = state.lastT;
  }
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
  stream.close();
  stream = connect();
});

makePlots();
let stream = connect();
setInterval(redraw, REDRAW_MS);
