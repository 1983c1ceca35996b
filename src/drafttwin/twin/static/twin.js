// drafttwin live page: one WebSocket for every machine; uPlot charts of the selected one.
"use strict";
const WINDOW_S = 30;
const token = new URLSearchParams(location.search).get("token");
const q = token ? "?token=" + encodeURIComponent(token) : "";
const state = { machines: {}, selected: null, charts: [], alarms: [], updates: 0 };

function el(tag, attrs, text) {
  const e = document.createElement(tag);
  Object.entries(attrs || {}).forEach(([k, v]) => e.setAttribute(k, v));
  if (text !== undefined) e.textContent = text;
  return e;
}

function fmt(x, d) { return x === null || x === undefined ? "–" : Number(x).toFixed(d); }

async function api(path) {
  const url = new URL(path, location.href);
  if (token) url.searchParams.set("token", token);
  const r = await fetch(url);
  if (!r.ok) throw new Error(path + ": " + r.status);
  return r.json();
}

function buffers(channels) {
  const k = channels.length;
  return { channels, t: [], measured: channels.map(() => []), physics: channels.map(() => []),
           twin: channels.map(() => []), residual: channels.map(() => []), k, last: null };
}

function push(m, rows) {
  const b = state.machines[m];
  if (!b) return;
  for (const r of rows) {
    b.t.push(r[0]);
    for (let j = 0; j < b.k; j++) {
      b.measured[j].push(r[3 + j]); b.physics[j].push(r[3 + b.k + j]);
      b.twin[j].push(r[3 + 2 * b.k + j]); b.residual[j].push(r[3 + 3 * b.k + j]);
    }
    b.last = r;
  }
  const cut = b.t.length ? b.t[b.t.length - 1] - WINDOW_S : 0;
  let i = 0;
  while (i < b.t.length && b.t[i] < cut) i++;
  if (i > 0) {
    b.t.splice(0, i);
    for (const key of ["measured", "physics", "twin", "residual"]) b[key].forEach(a => a.splice(0, i));
  }
}

// an alarm's test and its probable cause (kinds fault, fault-cause, sensor-fault: JSON detail)
function describe(a) {
  const f = a.fault;
  if (!f) return a.detail;
  const way = f.direction > 0 ? " up" : f.direction < 0 ? " down" : "";
  let text = `${f.test}${way}, onset ${new Date(f.onset_s * 1000).toISOString().slice(11, 19)}`;
  if (f.causes && f.causes.length) {
    text += " · probable cause: " + f.causes.map(c =>
      `${c.element} ${c.kind} ${fmt(c.severity, 3)} [${fmt(c.interval[0], 3)}, ${fmt(c.interval[1], 3)}] ` +
      `(p ${fmt(100 * c.probability, 0)} %)`).join("; ");
  }
  if (f.note) text += " · " + f.note;
  return text;
}

function faulted(name) {
  return state.alarms.some(a => a.machine === name && (a.fault || a.kind === "sliver-chimney"));
}

function tiles() {
  const hall = document.getElementById("hall");
  hall.replaceChildren();
  for (const [name, b] of Object.entries(state.machines)) {
    const t = el("div", { class: "tile " + (b.state || "") + (faulted(name) ? " fault" : "") +
                                   (name === state.selected ? " sel" : ""),
                          "data-machine": name });
    t.append(el("b", {}, name), el("br"));
    const r = b.last;
    const res = r ? Math.max(...b.channels.map((_, j) => Math.abs(r[3 + 3 * b.k + j] ?? 0))) : null;
    t.append(el("span", {}, `${b.state || "?"} · ${fmt(r && r[2], 2)} Hz · |res| ${fmt(res, 1)} rpm`));
    t.onclick = () => { state.selected = name; build(); };
    hall.append(t);
  }
}

function chart(title, series, width) {
  const opts = { title: "", width, height: 200, scales: { x: { time: false } },
                 series: [{ label: "s before newest" }, ...series], axes: [{}, { size: 60 }] };
  return new uPlot(opts, [[], ...series.map(() => [])], null);
}

function build() {
  const main = document.getElementById("charts");
  main.replaceChildren();
  state.charts = [];
  const b = state.machines[state.selected];
  if (!b) return;
  const width = Math.max(520, Math.floor(main.clientWidth / 2) - 40);
  b.channels.forEach((c, j) => {
    const card = el("div", { class: "card" });
    const h = el("h2", {}, c + " roller (rpm)");
    h.append(el("span", { class: "v", id: "value-" + c }, "–"));
    const u = chart(c, [{ label: "measured", stroke: "#888" }, { label: "physics", stroke: "#4b7bd0" },
                        { label: "twin", stroke: "#d9480f", width: 2 }], width);
    card.append(h, u.root);
    main.append(card);
    state.charts.push({ u, draw: x => u.setData([x, b.measured[j], b.physics[j], b.twin[j]]) });
  });
  const card = el("div", { class: "card" });
  card.append(el("h2", {}, "residuals: measured − twin (rpm)"));
  const colours = ["#d9480f", "#2e9d5b", "#4b7bd0", "#8a4bd0"];
  const u = chart("residual", b.channels.map((c, j) => ({ label: c, stroke: colours[j % 4] })), width);
  card.append(u.root);
  main.append(card);
  state.charts.push({ u, draw: x => u.setData([x, ...b.residual]) });
  const al = el("div", { class: "card" });
  al.append(el("h2", {}, "alarms and events"), el("div", { id: "alarms" }));
  main.append(al);
  tiles();
  draw();
}

function draw() {
  const b = state.machines[state.selected];
  if (!b) return;
  // x: seconds before the newest sample (epoch or replay times alike read as "0 = now")
  const newest = b.t.length ? b.t[b.t.length - 1] : 0;
  const x = b.t.map(v => v - newest);
  state.charts.forEach(c => c.draw(x));
  if (b.last) {
    b.channels.forEach((c, j) => {
      const v = document.getElementById("value-" + c);
      if (v) v.textContent = `measured ${fmt(b.last[3 + j], 1)} · twin ${fmt(b.last[3 + 2 * b.k + j], 1)}`;
    });
  }
  const box = document.getElementById("alarms");
  if (box) {
    box.replaceChildren(...state.alarms.slice(-100).reverse().map(a =>
      el("div", { class: a.fault || a.kind === "sliver-chimney" ? "fault" : "" },
         `${new Date(a.time * 1000).toISOString().slice(11, 23)} ${a.machine} ${a.kind}: ${describe(a)}`)));
  }
}

async function start() {
  const list = await api("api/machines");
  for (const m of list) {
    state.machines[m.machine] = Object.assign(buffers(m.channels), { state: m.state });
    const h = await api("api/history/" + encodeURIComponent(m.machine) + "?seconds=" + WINDOW_S);
    push(m.machine, h.rows);
  }
  state.alarms = await api("api/alarms");
  state.selected = list.length ? list[0].machine : null;
  build();
  const ws = new WebSocket((location.protocol === "https:" ? "wss://" : "ws://") + location.host +
                           location.pathname.replace(/[^/]*$/, "") + "ws" + q);
  ws.onmessage = ev => {
    const msg = JSON.parse(ev.data);
    for (const [m, rows] of Object.entries(msg.rows)) push(m, rows);
    state.alarms.push(...msg.events);
    state.updates++;
  };
  ws.onclose = () => { document.getElementById("status").textContent = "disconnected"; };
  setInterval(draw, 100);
  setInterval(async () => {
    try {
      const s = await api("api/status");
      for (const [m, st] of Object.entries(s.machines)) if (state.machines[m]) state.machines[m].state = st.state;
      const lat = s.latency_ms;
      document.getElementById("status").textContent =
        `${Object.keys(s.machines).length} machine(s) · ${s.rows} samples · p99 ${fmt(lat.p99, 1)} ms · updates ${state.updates}`;
      tiles();
    } catch (e) { document.getElementById("status").textContent = String(e); }
  }, 1000);
}
start();
