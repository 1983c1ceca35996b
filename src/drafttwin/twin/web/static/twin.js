// drafttwin pages: the live twin (index.html) and the hall (hall.html) share this file.
// Shared: formatting, the alarm book (active / acknowledged / returned to normal) and banner,
// the health summary of a machine. Twin page: one WebSocket for every machine, uPlot charts of
// the selected one on robust scales. Hall page: a tile per machine from /api/hall.
"use strict";
const PARAMS = new URLSearchParams(location.search);
const TOKEN = PARAMS.get("token");
const ALARM_KINDS = ["fault", "fault-cause", "sensor-fault", "fault-cleared", "alarm-ack", "sliver-chimney", "sliver-count"];
const SPIKE_REL = 0.10;   // the twin's spike rule: 10 % from both neighbours
const LIVE_KEEP_S = 600;  // live rows kept in the page, s
const GAP_S = 2;          // a longer gap between rows breaks the lines (the twin's own gap rule)
const SPANS = [["1 min", 60], ["5 min", 300], ["10 min", 600], ["1 h", 3600], ["6 h", 21600],
               ["24 h", 86400]];
const C = { measured: "#6b7280", physics: "#1f6fd1", twin: "#d9480f", spike: "#c2185b",
            limit: "#b00020", band: "#2e9d5b", setpoint: "#7b3fb5" };

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  Object.entries(attrs || {}).forEach(([k, v]) => e.setAttribute(k, v));
  if (text !== undefined) e.textContent = text;
  return e;
}
function fmt(x, d) { return x === null || x === undefined || !isFinite(x) ? "–" : Number(x).toFixed(d); }
function withUnit(x, d, unit) { return x === null || x === undefined || !isFinite(x) ? "–" : `${Number(x).toFixed(d)} ${unit}`; }
// the plant's clock: epoch seconds from a live source (local wall time), a file's own time in replay
function isEpoch(t) { return t > 1e9; }
function clock(t, ms) {
  if (t === null || t === undefined) return "–";
  if (!isEpoch(t)) return `${t.toFixed(ms ? 2 : 1)} s`;
  const d = new Date(t * 1000);
  const s = d.toLocaleTimeString([], { hour12: false });
  return ms ? `${s}.${String(d.getMilliseconds()).padStart(3, "0")}` : s;
}
async function api(path) {
  const url = new URL(path, location.href);
  if (TOKEN) url.searchParams.set("token", TOKEN);
  const r = await fetch(url);
  if (!r.ok) throw new Error(`${path}: ${r.status}`);
  return r.json();
}

// ---- alarms: the twin's book (every alarm active, or waiting for an operator) --------------
function causeText(f) {
  if (!f) return "";
  const c = f.causes ? f.causes[0] : f.cause;
  if (c) {
    const sev = c.severity === null || c.severity === undefined ? "" : ` severity ${fmt(c.severity, 3)}`;
    const p = c.probability === undefined ? "" : ` (p ${fmt(100 * c.probability, 0)} %)`;
    return `probable cause: ${c.element} ${c.kind}${sev}${p}`;
  }
  return f.note ? f.note : "probable cause pending";
}
function alarmTitle(a) {
  const f = a.fault;
  if (!f) return `${a.kind}: ${a.detail || ""}`;
  const way = f.direction > 0 ? " up" : f.direction < 0 ? " down" : "";
  return `${a.kind === "sensor-fault" ? "sensor fault" : "fault"} ${f.test}${way}, onset ${clock(f.onset_s)}`;
}
// the twin's own book (/api/alarms/active, most severe first, then the newest): an alarm stays
// active until its stream is back at the baseline it left (or the machine is serviced) and is
// shown until an operator acknowledged and confirmed it, on every page and client alike
const book = {
  list: [],
  load(list) { this.list = Array.isArray(list) ? list : []; },
  state(a) { return `${a.active ? "active" : "rtn"}-${a.acked ? "ack" : "unack"}`; },
  of(m) { return this.list.filter(a => a.machine === m); },
  worst(m) { const l = this.of(m); return l.length ? this.state(l[0]) : "normal"; },
};
const BANNER = { "active-unack": "ALARM", "active-ack": "ALARM · acknowledged",
                 "rtn-unack": "returned to normal · not acknowledged",
                 "rtn-ack": "returned to normal · acknowledged, not confirmed" };
async function post(path) {
  const url = new URL(path, location.href);
  if (TOKEN) url.searchParams.set("token", TOKEN);
  const r = await fetch(url, { method: "POST" });
  if (!r.ok) throw new Error(`${path}: ${r.status}`);
  return r.json();
}
function banners(redraw, canAct) {
  const box = document.getElementById("banner");
  if (!box) return;
  const out = [];
  for (const a of book.list) {
    const s = book.state(a);
    const b = el("div", { class: "banner " + s, "data-machine": a.machine, "data-alarm": a.id, role: "alert" });
    const way = a.direction > 0 ? " up" : a.direction < 0 ? " down" : "";
    b.append(el("b", {}, `${BANNER[s]} · ${a.machine}`),
             el("span", { class: "what" }, `${a.kind === "sensor-fault" ? "sensor fault" : "fault"} ${a.test}${way}`),
             el("span", { class: "cause" }, a.cause ? causeText({ cause: a.cause }) : "probable cause pending"),
             el("span", { class: "when" }, `at ${clock(a.time_s)}`));
    const act = !canAct ? null : !a.acked ? ["ack", "Acknowledge", "acknowledge"]
      : !a.confirmed ? ["confirm", "Confirm", "confirm"] : null;
    if (act) {
      const btn = el("button", { class: act[0] }, act[1]);
      btn.onclick = () => post(`api/machines/${encodeURIComponent(a.machine)}/alarms/${act[2]}?alarm=${encodeURIComponent(a.id)}`)
        .then(r => { book.list = book.list.filter(x => x.machine !== a.machine).concat(r.alarms); redraw(); })
        .catch(e => status(String(e)));
      b.append(btn);
    }
    out.push(b);
  }
  const html = out.map(b => b.outerHTML).join("");
  if (box.dataset.shown !== html) { box.replaceChildren(...out); box.dataset.shown = html; }
}

// ---- health: live, late samples, data age, p99 latency -------------------------------------
function health(name, m, p99, age, setpoint) {
  const t = el("div", { class: "health" });
  const fresh = age === null || age < 2;
  t.append(el("span", { class: "state " + (m.state === "live" && fresh ? "ok" : "warn") }, m.state || "?"));
  if (m.late !== undefined) t.append(el("span", { class: m.late ? "warn" : "" }, `late ${m.late}`));
  t.append(el("span", { class: "age " + (fresh ? "" : "warn") }, `data age ${withUnit(age, age !== null && age < 10 ? 2 : 0, "s")}`));
  t.append(el("span", { class: "p99" }, `p99 ${withUnit(p99, 1, "ms")}`));
  if (setpoint !== undefined) t.append(el("span", {}, `set-point ${withUnit(setpoint, 2, "Hz")}`));
  const d = m.detector;  // learning its healthy state: no fault alarm meanwhile
  if (d && d.state === "learning") {
    t.append(el("span", { class: "learning", title: "the machine's healthy state is being learned: no fault alarm meanwhile" },
      `learning ${Math.round(100 * (d.progress || 0))} %, ${withUnit(d.left_s, 0, "s")} left`));
  } else if (d && d.state === "watching") {
    const serial = m.identity ? m.identity.serial_number : null;
    t.append(el("span", { class: "watching", title: serial ? `baseline learned on ${serial}` : "baseline learned" }, "watched"));
  }
  return t;
}

// ---- robust scales -----------------------------------------------------------------------
function quantile(sorted, q) {
  if (!sorted.length) return null;
  const i = Math.min(sorted.length - 1, Math.max(0, Math.round(q * (sorted.length - 1))));
  return sorted[i];
}
// the y range from the 0.5 and 99.5 % quantiles of what is drawn (spikes left out), a margin
function robustRange(arrays, i0, i1, minSpan) {
  const v = [];
  for (const a of arrays) for (let i = i0; i < i1; i++) if (a[i] !== null && isFinite(a[i])) v.push(a[i]);
  if (!v.length) return [-1, 1];
  v.sort((x, y) => x - y);
  const lo = quantile(v, 0.005), hi = quantile(v, 0.995);
  const pad = Math.max(0.1 * (hi - lo), minSpan / 2);
  return [lo - pad, hi + pad];
}

// ---- the twin page -----------------------------------------------------------------------
const state = { machines: {}, selected: null, charts: [], events: [], updates: 0, status: null,
                view: { live: true, span: 60, x0: null, x1: null }, history: null };
window.twinPage = state;

function buffers(channels) {
  const n = channels.length;
  const arr = () => channels.map(() => []);
  return { channels, k: n, t: [], sp: [], meas: arr(), phys: arr(), twin: arr(), res: arr(),
           spike: arr(), last: null };
}
function num(v) { return v === null || v === undefined || !isFinite(v) ? null : v; }
// the paper's both-neighbours rule: a spike differs by more than SPIKE_REL from the nearest
// good sample before it and the nearest after it (a level step is followed by its next sample);
// the newest sample, with none after it yet, by the one before it alone until its next comes
function neighbour(a, spike, i, step) {
  for (let k = i + step, n = 0; k >= 0 && k < a.length && n < 5; k += step, n++) {
    if (a[k] !== null && !(step < 0 && spike[k])) return a[k];
  }
  return null;
}
function isSpike(a, spike, i) {
  const v = a[i], p = neighbour(a, spike, i, -1), n = neighbour(a, spike, i, 1);
  if (v === null || p === null) return false;
  const tol = SPIKE_REL * Math.max(Math.abs(p), n === null ? 0 : Math.abs(n), 1);
  return Math.abs(v - p) > tol && (n === null || Math.abs(v - n) > tol);
}
function push(b, rows) {
  for (const r of rows) {
    const last = newest(b);
    if (last !== null && r[0] - last > GAP_S) pushBreak(b, last);
    b.t.push(r[0]); b.sp.push(num(r[2]));
    for (let j = 0; j < b.k; j++) {
      b.meas[j].push(num(r[3 + j])); b.phys[j].push(num(r[3 + b.k + j]));
      b.twin[j].push(num(r[3 + 2 * b.k + j])); b.res[j].push(num(r[3 + 3 * b.k + j]));
      const i = b.t.length - 1;
      b.spike[j].push(false);
      if (i >= 1) b.spike[j][i - 1] = isSpike(b.meas[j], b.spike[j], i - 1);
      b.spike[j][i] = isSpike(b.meas[j], b.spike[j], i);
    }
    b.last = r;
  }
  const cut = b.t.length ? b.t[b.t.length - 1] - LIVE_KEEP_S : 0;
  let i = 0;
  while (i < b.t.length && b.t[i] < cut) i++;
  if (i > 0) {
    b.t.splice(0, i); b.sp.splice(0, i);
    for (const key of ["meas", "phys", "twin", "res", "spike"]) b[key].forEach(a => a.splice(0, i));
  }
}
// a row of nothing just after the last before a gap: the lines break there instead of
// joining the samples on either side with a straight line
function pushBreak(b, last) {
  b.t.push(last + 1e-3); b.sp.push(null);
  for (const key of ["meas", "phys", "twin", "res"]) b[key].forEach(a => a.push(null));
  b.spike.forEach(a => a.push(false));
}
function newest(b) { return b && b.t.length ? b.t[b.t.length - 1] : null; }
function dataNow(m) {  // the machine's data time now (s): its newest sample
  const b = state.machines[m];
  return b ? newest(b) : null;
}

function series(label, stroke, unit, extra) {
  return Object.assign({ label, stroke, width: 1, spanGaps: false,
                         value: (u, v) => withUnit(v, 1, unit) }, extra || {});
}
// a chart whose x and y come from the page (drawPage), with a hook for spike markers
function chart(b, width, height, list, extra) {
  const epoch = b.t.length ? isEpoch(b.t[0]) : true;
  const opts = {
    width, height, legend: { live: true },
    scales: { x: { time: epoch, range: () => [state.view.x0, state.view.x1] },
              y: { range: u => u.yRange || [-1, 1] } },
    series: [{ label: epoch ? "time" : "record time", value: (u, v) => clock(v, true) }, ...list],
    axes: [{ space: 90, values: (u, s) => s.map(v => (epoch ? clock(v, s.length > 1 && s[1] - s[0] < 1) : `${v} s`)) },
           { size: 64, label: extra.unit, labelSize: 14 }],
    cursor: { sync: { key: "twin" }, drag: { x: true, y: false, setScale: false } },
    hooks: { draw: [u => (extra.draw ? extra.draw(u) : null)],
             setSelect: [u => zoomFromSelect(u)] },
  };
  const u = new uPlot(opts, [[], ...list.map(() => [])], null);
  u.over.ondblclick = () => goLive(state.view.span);
  return u;
}
function zoomFromSelect(u) {
  if (u.select.width < 4) return;
  const x0 = u.posToVal(u.select.left, "x"), x1 = u.posToVal(u.select.left + u.select.width, "x");
  u.setSelect({ left: 0, top: 0, width: 0, height: 0 }, false);
  Object.assign(state.view, { live: false, x0, x1 });
  drawPage();
}
// spikes off the axis: a triangle at the edge they left by, with their value
function markSpikes(u, b, j, values) {
  const ctx = u.ctx, [y0, y1] = u.yRange || [0, 0];
  const i0 = u.idx0 || 0, i1 = u.idx1 || 0;
  ctx.save();
  ctx.fillStyle = C.spike; ctx.font = `${Math.round(10 * devicePixelRatio)}px sans-serif`;
  ctx.textAlign = "left"; ctx.textBaseline = "alphabetic";
  let n = 0, labelled = -Infinity;
  for (let i = i0; i < i1; i++) {
    if (!b.spike[j][i] || values[i] === null) continue;
    n++;
    const x = u.valToPos(b.t[i], "x", true);
    const up = values[i] > (y0 + y1) / 2;
    const y = up ? u.bbox.top : u.bbox.top + u.bbox.height, s = 6 * devicePixelRatio;
    ctx.beginPath();
    ctx.moveTo(x - s, up ? y + s * 1.6 : y - s * 1.6); ctx.lineTo(x + s, up ? y + s * 1.6 : y - s * 1.6);
    ctx.lineTo(x, y); ctx.closePath(); ctx.fill();
    if (x - labelled > 40 * devicePixelRatio) {  // labels that would overlap: the first only
      ctx.fillText(fmt(values[i], 0), x + s + 2, up ? y + s * 1.6 : y - 2);
      labelled = x;
    }
  }
  ctx.restore();
  u.spikesShown = n;
}
// the residual's limits: the detector's (from /api/model, when it sends them) or a robust band
function drawLimits(u, lim, label) {
  if (!lim) return;
  const ctx = u.ctx;
  ctx.save();
  const colour = label.startsWith("detector") ? C.limit : C.band;
  ctx.strokeStyle = colour;
  ctx.setLineDash([6 * devicePixelRatio, 4 * devicePixelRatio]); ctx.lineWidth = devicePixelRatio;
  for (const v of [lim, -lim]) {
    const y = u.valToPos(v, "y", true);
    ctx.beginPath(); ctx.moveTo(u.bbox.left, y); ctx.lineTo(u.bbox.left + u.bbox.width, y); ctx.stroke();
  }
  ctx.restore();
  // named under the chart, not on it: a label on the line sat under the spike markers' values
  const note = u.root.parentElement && u.root.parentElement.querySelector(".limit");
  const text = `- - - ${label} ±${fmt(lim, 2)} rpm`;
  if (note && note.textContent !== text) { note.textContent = text; note.style.color = colour; }
}

function build() {
  const main = document.getElementById("charts");
  main.replaceChildren();
  state.charts = [];
  const b = state.machines[state.selected];
  if (!b) return;
  state.empty = !b.t.length;  // no sample yet: a note instead of empty axes; the charts come with the first
  if (state.empty) {
    const note = el("div", { class: "card", id: "no-samples" });
    note.append(el("h2", {}, `${state.selected}: no sample yet`), el("div", { id: "no-samples-text" }));
    main.append(note);
  }
  // as wide as a card of the grid (index.html: columns of at least 560 px, 10 px apart, 16 px
  // padding; a card's own 8 px): a narrow window had 520-px charts in a 700-px card
  const content = main.clientWidth - 32;
  const columns = Math.max(1, Math.floor((content + 10) / 570));
  const width = Math.max(300, Math.floor((content - 10 * (columns - 1)) / columns) - 18);
  if (!state.empty) b.channels.forEach((c, j) => {
    const card = el("div", { class: "card", "data-channel": c });
    const h = el("h2", {}, `${c} roller`);
    h.append(el("span", { class: "v", id: "spikes-" + c }, ""));
    const speed = chart(b, width, 200, [
      series("measured", C.measured, "rpm"),
      series("twin", C.twin, "rpm", { width: 2 }),
      series("physics", C.physics, "rpm", { width: 2, dash: [8, 5] })],  // dashed, on top
      { unit: "speed, rpm", draw: u => markSpikes(u, b, j, b.meas[j]) });
    const res = chart(b, width, 120, [series("measured − twin", C.twin, "rpm")],
      { unit: "residual, rpm", draw: u => { drawLimits(u, u.limit, u.limitLabel); markSpikes(u, b, j, b.res[j]); } });
    card.append(h, speed.root, res.root, el("div", { class: "limit" }));
    main.append(card);
    state.charts.push({ kind: "speed", channel: c, u: speed, j }, { kind: "residual", channel: c, u: res, j });
  });
  if (!state.empty) {
    const sp = el("div", { class: "card" });
    sp.append(el("h2", {}, "set-point (motor supply)"));
    const u = chart(b, width, 120, [series("set-point", C.setpoint, "Hz", { width: 2 })], { unit: "supply, Hz" });
    sp.append(u.root);
    main.append(sp);
    state.charts.push({ kind: "setpoint", u });
  }
  const sl = el("div", { class: "card", id: "sliver-card", hidden: "" });
  sl.append(el("h2", {}, "sliver and leveller"), el("div", { id: "sliver" }));
  const spec = chartSpectrogram(width);
  sl.append(spec.root);
  main.append(sl);
  state.spectrogram = spec;
  const ev = el("div", { class: "card" });
  ev.append(el("h2", {}, "alarms and events"), el("div", { id: "events" }));
  main.append(ev);
  drawPage();
  drawSliver();
}

// ---- the sliver: running count and CV, the last spectrogram, the leveller's recommendation ----
function wavelengthTick(v) {  // a log axis: 1, 2 and 5 of each decade labelled
  if (!(v > 0)) return null;
  const m = v / 10 ** Math.floor(Math.log10(v) + 1e-9);
  if (![1, 2, 5].some(k => Math.abs(m - k) < 1e-6)) return null;
  return v < 1 ? `${+(100 * v).toPrecision(2)} cm` : `${+v.toPrecision(2)} m`;
}
function chartSpectrogram(width) {
  const opts = {
    width, height: 160, legend: { live: true },
    scales: { x: { time: false, distr: 3 }, y: { range: (u, lo, hi) => [0, Math.max(hi || 0, 0.1) * 1.1] } },
    series: [{ label: "wavelength", value: (u, v) => (v === null || v === undefined ? "–" : v < 1 ? `${fmt(100 * v, 2)} cm` : `${fmt(v, 2)} m`) },
             { label: "amplitude", stroke: C.twin, width: 2, points: { show: true, size: 4 }, value: (u, v) => withUnit(v, 3, "%") },
             { label: "random sliver", stroke: C.physics, width: 1, dash: [6, 4], value: (u, v) => withUnit(v, 3, "%") },
             { label: "chimney", stroke: C.limit, width: 0, points: { show: true, size: 9, fill: C.limit }, paths: () => null, value: (u, v) => withUnit(v, 3, "%") },
             { label: "machine's own line", stroke: C.measured, width: 0, points: { show: true, size: 9, fill: C.measured }, paths: () => null, value: (u, v) => withUnit(v, 3, "%") }],
    axes: [{ values: (u, s) => s.map(wavelengthTick) },
           { size: 64, label: "amplitude, %", labelSize: 14 }],
  };
  return new uPlot(opts, [[], [], [], [], []], null);
}
// CV at 1 m, where the window was long enough to estimate it (a short one gives none)
function cv1m(a) {
  const [now, then] = [a.current.cv_1m_pct, a.recommended.cv_1m_pct].map(num);
  if (now === null && then === null) return " (CV 1 m: the window is too short for it)";
  return `, CV 1 m ${fmt(now, 3)} → ${withUnit(then, 3, "%")}`;
}
function drawSliver() {
  const card = document.getElementById("sliver-card"), box = document.getElementById("sliver");
  if (!card || !box) return;
  const m = state.status && state.status.machines[state.selected];
  const s = m ? m.sliver : null, l = m ? m.leveller : null;
  card.hidden = !s && !l;
  if (card.hidden) return;
  const lines = [];
  if (s) {
    lines.push(el("div", { class: "sliver-count" }, `count ${withUnit(s.count_ktex, 4, "ktex")} · CV ${withUnit(s.cv_pct, 3, "%")} · ` +
      `${withUnit(s.delivered_m, 1, "m")} delivered · ${s.alarms} chimney alarm(s)`));
    const lim = s.count_limit;
    lines.push(el("div", { class: lim && lim.outside ? "count-limit alarm" : "count-limit" }, lim ?
      `count limit ±${fmt(lim.limit_pct, 0)} % of the nominal ${withUnit(lim.nominal_ktex, 3, "ktex")} over ${withUnit(lim.length_m, 0, "m")}: ` +
      (lim.outside ? "OFF the limit now" : "within") + ` · ${lim.excursions} excursion(s)` :
      "count limit not watched: the machine names no nominal count"));
    const ch = s.chimneys || [];
    lines.push(el("div", { class: "chimneys" }, ch.length ? "chimneys: " + ch.map(c =>
      `${fmt(100 * c.wavelength_m, 2)} cm ${fmt(c.amplitude_pct, 3)} % (${c.element})`).join(", ") :
      s.spectrogram ? "no chimney in the last spectrogram" : "the first spectrogram after 100 m"));
    const own = s.own_lines || [];
    const learnt = s.learning ? "learning the machine's own lines (no chimney alarm meanwhile)" :
      s.learned ? `the machine's own lines, learned over ${withUnit(s.learned.metres, 0, "m")}, do not alarm` : "";
    if (learnt || own.length) lines.push(el("div", { class: "own-lines" }, learnt + (own.length ? ": " + own.map(c =>
      `${fmt(100 * c.wavelength_m, 2)} cm ${fmt(c.amplitude_pct, 3)} % (${c.element})`).join(", ") : "")));
  }
  if (l) {
    const set = l.setting || {};
    const setting = set.leveller ? `action point ${withUnit(set.action_point_mm, 1, "mm")}, intensity ${fmt(set.intensity, 2)}` : "no leveller";
    lines.push(el("div", {}, `leveller (${l.state}): the machine's setting ${setting}`));
    const a = l.advice;
    if (a && !a.identifiable) {  // the window does not place the action point: nothing recommended
      lines.push(el("div", { class: "advice" }, `no recommendation: these ${withUnit(a.metres_used, 0, "m")} ` +
        `do not say where the action point is (CV now ${withUnit(a.current.cv_pct, 3, "%")}).`));
    } else if (a) {
      const [lo, hi] = a.action_point_interval_mm;
      lines.push(el("div", { class: "advice" }, `recommended: action point ${withUnit(a.recommended_action_point_mm, 1, "mm")} ` +
        `(95 % ${fmt(lo, 1)}–${fmt(hi, 1)}), intensity ${fmt(a.recommended_intensity, 2)}: CV ${withUnit(a.current.cv_pct, 3, "%")} → ` +
        `${withUnit(a.recommended.cv_pct, 3, "%")} expected${cv1m(a)}; ` +
        `from ${withUnit(a.metres_used, 0, "m")} (within ±5 mm from ${withUnit(a.metres_needed, 0, "m")}). The twin writes no setting.`));
    } else {
      lines.push(el("div", {}, l.failed ? `no recommendation: ${l.failed}` :
        `collecting ${withUnit(l.collected_m, 0, "m")} of ${withUnit(l.window_m, 0, "m")}`));
    }
    if (a && l.failed) lines.push(el("div", { class: "note" }, `the last window: ${l.failed}`));
    for (const n of (a && a.notes) || []) lines.push(el("div", { class: "note" }, `note: ${n}`));
  }
  const html = lines.map(x => x.outerHTML).join("");
  if (box.dataset.shown !== html) { box.replaceChildren(...lines); box.dataset.shown = html; }
  const g = s && s.spectrogram, u = state.spectrogram;
  if (u && g) {
    const own = g.own || g.wavelength_m.map(() => false);  // the machine's own lines apart
    const chim = g.amplitude_pct.map((v, i) => (g.chimney[i] && !own[i] ? v : null));
    const mine = g.amplitude_pct.map((v, i) => (own[i] ? v : null));
    u.setData([g.wavelength_m, g.amplitude_pct, g.ideal_pct || g.wavelength_m.map(() => null), chim, mine]);
  }
}

// the rows shown: live (the buffer's last span) or a range (history from the store, or a zoom)
function shown(b) {
  const h = state.history;
  if (!state.view.live && h && h.machine === state.selected && state.view.x0 < (b.t[0] ?? Infinity)) return h.buf;
  return b;
}
// what the page says while the selected machine has sent nothing: its state and the twin's word on it
function drawWaiting(live) {
  const box = document.getElementById("no-samples-text");
  if (!box) return;
  const m = state.status && state.status.machines[state.selected];
  const st = (m && m.state) || live.state || "connecting";
  const said = state.events.filter(e => e.machine === state.selected && e.kind === "no-samples").pop();
  const text = `state ${st}: the charts appear with the machine's first sample.` +
    (said ? ` ${clock(said.time)}: ${said.detail}` : "");
  if (box.textContent !== text) box.textContent = text;
}
function drawPage() {
  const live = state.machines[state.selected];
  if (!live) return;
  if (state.empty) {
    if (live.t.length) { build(); return; }  // the first sample: the charts now have something to show
    drawWaiting(live);
    drawEvents();
    tiles();
    return;
  }
  if (state.view.live) {
    const t1 = newest(live) ?? 0;
    const t0 = live.t.length ? live.t[0] : t1;  // the window grows until it is full
    Object.assign(state.view, { x0: Math.max(t1 - state.view.span, Math.min(t0, t1 - 1)), x1: t1 });
  }
  const b = shown(live);
  let i0 = 0;
  while (i0 < b.t.length && b.t[i0] < state.view.x0) i0++;
  let i1 = i0;
  while (i1 < b.t.length && b.t[i1] <= state.view.x1) i1++;
  for (const c of state.charts) {
    const u = c.u, j = c.j;
    u.idx0 = i0; u.idx1 = i1;
    let data;
    if (c.kind === "speed") {
      const clean = b.meas[j].map((v, i) => (b.spike[j][i] ? null : v));
      u.yRange = robustRange([clean, b.phys[j], b.twin[j]], i0, i1, 2);
      data = [b.t, clean, b.twin[j], b.phys[j]];
      const n = b.spike[j].slice(i0, i1).filter(Boolean).length;
      const s = document.getElementById("spikes-" + c.channel);
      if (s) s.textContent = n ? `${n} spike(s) marked ▲▼, off the axis` : "";
    } else if (c.kind === "residual") {
      const clean = b.res[j].map((v, i) => (b.spike[j][i] ? null : v));
      const [lim, label] = limitOf(c.channel, clean, i0, i1);
      const [lo, hi] = robustRange([clean], i0, i1, 1);
      const half = Math.max(Math.abs(lo), Math.abs(hi), lim ? 1.25 * lim : 0, 0.5);
      u.yRange = [-half, half]; u.limit = lim; u.limitLabel = label;
      data = [b.t, clean];
    } else {
      u.yRange = robustRange([b.sp], i0, i1, 0.5);
      data = [b.t, b.sp];
    }
    u.setData(data);
    if (u.cursor.left === undefined || u.cursor.left < 0) u.setLegend({ idx: lastComplete(data, i0, i1) });
  }
  drawEvents();
  tiles();
}
// the legend off the cursor: the newest row in which every line has a value (the newest
// itself may be a rejected spike, whose measured value is none)
function lastComplete(data, i0, i1) {
  for (let i = i1 - 1; i >= Math.max(i0, i1 - 200); i--) {
    if (data.slice(1).every(col => col[i] !== null && col[i] !== undefined && isFinite(col[i]))) return i;
  }
  return i1 > i0 ? i1 - 1 : null;
}
function limitOf(channel, clean, i0, i1) {
  const det = state.limits && state.limits[channel];
  if (det) return [det, "detector limit"];
  // no detector limits from the API: 4 standard deviations of the window's residual, trimmed
  // to its 1-99 % quantiles (encoder counts are quantised: a MAD is often 0)
  const v = clean.slice(i0, i1).filter(x => x !== null).sort((x, y) => x - y);
  if (v.length < 20) return [null, ""];
  const lo = quantile(v, 0.01), hi = quantile(v, 0.99);
  const kept = v.filter(x => x >= lo && x <= hi);
  const mean = kept.reduce((a, x) => a + x, 0) / kept.length;
  const sd = Math.sqrt(kept.reduce((a, x) => a + (x - mean) ** 2, 0) / Math.max(1, kept.length - 1));
  return [Math.max(4 * sd, 0.05), "4σ band of the window"];
}

function drawEvents() {
  const box = document.getElementById("events");
  if (box) {
    box.replaceChildren(...state.events.slice(-100).reverse().map(a =>
      el("div", { class: ALARM_KINDS.includes(a.kind) ? "alarm" : "" },
         `${clock(a.time)} ${a.machine} ${ALARM_KINDS.includes(a.kind) ? alarmTitle(a) : a.kind + ": " + a.detail}` +
         (a.fault && a.kind !== "fault" ? " · " + causeText(a.fault) : ""))));
  }
  banners(drawPage, true);
}

// a tile per machine, made once and updated in place (a click must not land on a replaced one)
function tiles() {
  const hall = document.getElementById("hall");
  const s = state.status;
  for (const [name, b] of Object.entries(state.machines)) {
    let t = hall.querySelector(`.tile[data-machine="${CSS.escape(name)}"]`);
    if (!t) {
      t = el("div", { "data-machine": name });
      t.append(el("b", {}, name), el("div"));
      t.onclick = () => { state.selected = name; state.history = null; build(); };
      hall.append(t);
    }
    const m = (s && s.machines[name]) || { state: b.state };
    const n = newest(b);
    const age = typeof m.data_age_s === "number" ? m.data_age_s : n !== null && isEpoch(n) ? Date.now() / 1000 - n : null;
    const p99 = m.latency_ms ? m.latency_ms.p99 : s && s.latency_ms ? s.latency_ms.p99 : null;
    t.className = `tile ${m.state || ""} alarm-${book.worst(name)}` + (name === state.selected ? " sel" : "");
    t.lastChild.replaceWith(health(name, m, p99, age, b.last ? num(b.last[2]) : undefined));
  }
}

// a machine's rows from the history API, every page of the answer (its `next` cursor)
async function historyRows(m, query) {
  const rows = [], path = `api/history/${encodeURIComponent(m)}?${query}`;
  let h = await api(path);
  rows.push(...h.rows);
  for (let page = 1; h.next && page < 20; page++) {
    h = await api(`${path}&cursor=${encodeURIComponent(h.next)}`);
    rows.push(...h.rows);
  }
  return rows;
}
async function loadRange(span) {
  const m = state.selected, b = state.machines[m];
  const end = newest(b) ?? Date.now() / 1000, start = end - span;
  const rows = await historyRows(m, `start=${start}&end=${end}&points=2000`);
  const buf = buffers(b.channels);
  push(buf, rows.filter(r => r[0] >= start));
  state.history = { machine: m, buf };
  Object.assign(state.view, { live: false, x0: start, x1: end });
  drawPage();
}
function goLive(span) {
  Object.assign(state.view, { live: true, span });
  state.history = null;
  drawPage();
}
function controls() {
  const box = document.getElementById("range");
  SPANS.forEach(([label, s]) => {
    const btn = el("button", { "data-span": s }, label);
    btn.onclick = () => (s <= LIVE_KEEP_S ? goLive(s) : loadRange(s).catch(e => status(String(e))));
    box.append(btn);
  });
  box.append(el("span", { class: "hint" }, "drag on a chart to zoom, double-click for live"));
}
function status(text) { document.getElementById("status").textContent = text; }

async function startTwin() {
  // the stream first: rows that arrive while the history loads are kept and joined to it, so
  // the page has no gap where history meets the stream
  const early = [];
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host +
                           location.pathname.replace(/[^/]*$/, "") + "ws" + (TOKEN ? "?token=" + encodeURIComponent(TOKEN) : ""));
  let ready = false;
  const take = msg => {
    for (const [m, rows] of Object.entries(msg.rows)) {
      const b = state.machines[m];
      if (!b) continue;
      const last = newest(b);
      push(b, last === null ? rows : rows.filter(r => r[0] > last));  // after the history's end
    }
    if (msg.events.length) {
      state.events.push(...msg.events);
      if (msg.events.some(e => ALARM_KINDS.includes(e.kind))) loadAlarms();
    }
    state.updates++;
  };
  ws.onmessage = ev => { const msg = JSON.parse(ev.data); if (ready) take(msg); else early.push(msg); };
  ws.onclose = () => status("disconnected");
  const list = await api("api/machines");
  for (const m of list) {
    state.machines[m.machine] = Object.assign(buffers(m.channels), { state: m.state });
    push(state.machines[m.machine], await historyRows(m.machine, "seconds=60"));
  }
  const alarms = await api("api/alarms");
  const others = await api("api/events").catch(() => []);  // an older twin: alarms held all
  state.events = [...alarms, ...others.filter(e => !ALARM_KINDS.includes(e.kind))].sort((a, b) => a.time - b.time);
  await loadAlarms();
  // the detector's residual limits, rpm per channel, when the API sends them (else a 4σ band)
  const model = list.length ? await api("api/model/" + encodeURIComponent(list[0].machine)).catch(() => ({})) : {};
  state.limits = model.residual_limits_rpm || null;
  state.selected = list.length ? list[0].machine : null;
  early.splice(0).forEach(take);
  ready = true;
  controls();
  build();
  setInterval(drawPage, 250);
  const poll = async () => {
    try {
      const s = await api("api/status");
      state.status = s;
      for (const [m, st] of Object.entries(s.machines)) if (state.machines[m]) state.machines[m].state = st.state;
      status(`${Object.keys(s.machines).length} machine(s) · ${s.rows} samples · p99 ${withUnit(s.latency_ms.p99, 1, "ms")} (all machines)`);
      drawSliver();
    } catch (e) { status(String(e)); }
    loadAlarms();
  };
  poll(); setInterval(poll, 1000);
}
async function loadAlarms() {
  try { book.load(await api("api/alarms/active")); } catch (e) { /* an older twin: none */ }
}

// ---- the hall page -----------------------------------------------------------------------
const hallState = { hall: null };
async function drawHall() {
  const h = await api("api/hall");
  hallState.hall = h;
  const root = document.getElementById("hall");
  root.replaceChildren();
  let machines = 0, alarms = 0;
  const standing = [];
  for (const s of h.shards) {
    const p99 = s.latency_ms ? s.latency_ms.p99 : null;
    root.append(el("h2", {}, `shard ${s.shard}: ${s.state} · ${s.rows ?? 0} samples · p99 ${withUnit(p99, 1, "ms")}`));
    const box = el("div", { class: "shard" });
    for (const [name, m] of Object.entries(s.machines)) {
      machines++;
      standing.push(...(m.active_alarms || []));
      const mine = (m.active_alarms || []).map(a => book.state(a));
      if (mine.length) alarms++;
      const t = el("div", { class: `tile ${m.state} alarm-${mine.length ? mine[0] : "normal"}`, "data-machine": name });
      const age = typeof m.data_age_s === "number" ? m.data_age_s : null;
      t.append(el("b", {}, name), health(name, m, m.latency_ms ? m.latency_ms.p99 : p99, age),
               el("span", { class: "count" }, `${m.processed ?? 0} samples · ${mine.length} alarm(s) standing`));
      const top = (m.active_alarms || [])[0];  // the most severe standing alarm, else the last
      const c = top ? (top.cause ? causeText({ cause: top.cause }) : `${top.test}: probable cause pending`)
        : m.last_fault ? causeText(m.last_fault) : "";
      if (c) t.append(el("span", { class: "cause" }, c));
      box.append(t);
    }
    root.append(box);
  }
  standing.sort((a, b) => b.severity - a.severity || b.time_s - a.time_s);
  book.load(standing);
  banners(() => drawHall(), true);  // acknowledged / confirmed through the machine's shard
  status(`${machines} machine(s) · ${alarms} with alarms · updated ${clock(h.updated)}`);
}
function startHall() {
  const tick = () => drawHall().catch(() => status("· disconnected"));
  tick(); setInterval(tick, 1000);
}

if (document.body.dataset.page === "hall") startHall(); else startTwin();
