/* siva live dashboard: polls the public API and draws with the vendored uPlot.
 *
 * Defensive by design: the estimate and drift payloads are evolving, so every panel reads
 * what it needs with fallbacks and says "not yet available" when a key is missing, rather
 * than throwing (a thrown error would stop the polling loop for every panel).
 */
"use strict";

const POLL_MS = 3000;          // fleet, estimate, drift
const LATEST_EVERY = 3;        // latest-record every 3rd poll (the server caches it anyway)
const COLORS = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2"];

const state = { selected: null, tick: 0, plots: {}, diagnosisPath: null, openapiChecked: false };

// ------------------------------------------------------------------ helpers
function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  for (const [k, v] of Object.entries(attrs || {})) {
    if (k === "class") e.className = v; else if (k === "text") e.textContent = v;
    else if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
  }
  for (const c of children) if (c != null) e.append(c);
  return e;
}
function na(text) { return el("div", { class: "na", text: text || "not yet available" }); }
function fmt(x, digits) {
  if (x === null || x === undefined || typeof x !== "number" || !isFinite(x)) return "–";
  const d = digits || 5;
  const a = Math.abs(x);
  return (a !== 0 && (a < 1e-3 || a >= 1e6)) ? x.toExponential(d - 1) : String(Number(x.toPrecision(d)));
}
function localTime(t) {
  return typeof t === "number" && isFinite(t) ? new Date(t * 1000).toLocaleString() : "–";
}
async function getJSON(path) {
  const r = await fetch(path, { headers: { Accept: "application/json" } });
  if (!r.ok) { const e = new Error(path + ": HTTP " + r.status); e.status = r.status; throw e; }
  return r.json();
}
function get(obj, ...keys) {
  for (const k of keys) { if (obj == null) return undefined; obj = obj[k]; }
  return obj;
}

// ------------------------------------------------------------------ plots (uPlot)
function plotWidth(container, fraction) {
  const w = container.clientWidth || 600;
  return Math.max(260, Math.floor(w * (fraction || 1)) - 12);
}
/** A linear range that uPlot can draw: uPlot 1.6.32 loops forever building axis ticks
 * (RangeError: Invalid array length after seconds of 100 % CPU, leeoniya/uPlot#1084) when a
 * scale's min and max are equal up to float noise - e.g. a converged parameter or a
 * float32 ensemble mean that only jitters in its 7th digit, or a single point.  So: pad a
 * range narrower than 1e-6 of its magnitude to +-0.1 % (at least 1e-12), and refuse
 * non-finite ends. */
function safeLinear(u, lo, hi) {
  if (lo == null || hi == null || !isFinite(lo) || !isFinite(hi)) return [0, 1];
  if (lo > hi) [lo, hi] = [hi, lo];
  const mag = Math.max(Math.abs(lo), Math.abs(hi));
  const pad = (hi - lo) * 0.05;
  if (hi - lo <= 1e-6 * mag || hi - lo < 1e-12) {
    const mid = (lo + hi) / 2, w = Math.max(1e-3 * Math.abs(mid), 1e-12);
    return [mid - w, mid + w];
  }
  return [lo - pad, hi + pad];
}
/** A time range [s] uPlot can draw: at least a minute wide. */
function safeTime(u, lo, hi) {
  if (lo == null || hi == null || !isFinite(lo) || !isFinite(hi)) { const now = Date.now() / 1000; return [now - 60, now]; }
  return hi - lo < 60 ? [hi - 60, hi + 1] : [lo, hi];
}
/** A log range (decades) from the data's positive extremes: at most 4 decades below the
 * peak, finite, never [0, 0] or lo >= hi. */
function safeLog(u, lo, hi) {
  if (!(hi > 0) || !isFinite(hi)) return [1e-6, 1];
  const top = Math.min(hi * 2, Number.MAX_VALUE / 10);
  let bottom = (lo > 0 && isFinite(lo)) ? Math.max(lo, hi * 1e-4) : hi * 1e-4;
  bottom = Math.pow(10, Math.floor(Math.log10(bottom)));  // a decade: ticks at 10^k only
  return bottom > 0 && bottom < top / 1.01 ? [bottom, top] : [top / 100, top];
}
/** Create or update a uPlot keyed by id; re-created when the series layout changes. */
function upsertPlot(id, container, opts, data) {
  const sig = JSON.stringify(opts.series.map(s => s.label)) + (opts.title || "");
  let p = state.plots[id];
  if (p && (p.sig !== sig || !container.contains(p.u.root))) { p.u.destroy(); p = null; }
  if (!p) {
    opts.legend = Object.assign({ live: false }, opts.legend || {});
    opts.scales = opts.scales || {};
    for (const k of ["x", "y"]) {  // every scale gets a range uPlot can draw (safeLinear)
      const sc = opts.scales[k] = opts.scales[k] || {};
      if (!sc.range && sc.distr !== 3) sc.range = sc.time ? safeTime : safeLinear;
    }
    const timeX = get(opts, "scales", "x", "time");
    (opts.axes || []).forEach((a, i) => { if (!a.values && !(i === 0 && timeX)) a.values = (u, vals) => vals.map(v => fmt(v, 3)); });
    const u = new uPlot(opts, data, container);
    state.plots[id] = p = { u, sig };
  } else {
    p.u.setData(data);
  }
  return p.u;
}
function dropPlots(prefix) {
  for (const id of Object.keys(state.plots)) {
    if (id.startsWith(prefix)) { state.plots[id].u.destroy(); delete state.plots[id]; }
  }
}
/** uPlot hook: vertical red lines at the given x values (alarm epochs). */
function markersPlugin(xs, color) {
  return { hooks: { draw: [u => {
    const ctx = u.ctx; ctx.save(); ctx.strokeStyle = color || "#d62728"; ctx.lineWidth = 1.5;
    for (const x of xs) {
      const px = u.valToPos(x, "x", true);
      if (px < u.bbox.left || px > u.bbox.left + u.bbox.width) continue;
      ctx.beginPath(); ctx.moveTo(px, u.bbox.top); ctx.lineTo(px, u.bbox.top + u.bbox.height); ctx.stroke();
    }
    ctx.restore();
  }] } };
}

// ------------------------------------------------------------------ fleet
function renderFleet(systems) {
  const body = document.querySelector("#fleet tbody");
  body.replaceChildren();
  if (!systems.length) { body.append(el("tr", {}, el("td", { colspan: 6, class: "na", text: "no system yet" }))); return; }
  for (const s of systems) {
    const n = s.n_recordings || {};
    const alarms = s.active_alarms || [];
    const tr = el("tr", { onclick: () => select(s.name) },
      el("td", { text: s.name }),
      el("td", {}, el("span", { class: "badge " + (s.state || ""), text: s.state || "–" })),
      el("td", { class: "num", text: String(s.epoch ?? "–") }),
      el("td", { text: s.converged ? "yes" : "no" }),
      el("td", { class: "num", text: `${n.train ?? 0} / ${n.validation ?? 0}` }),
      el("td", {}, alarms.length ? el("span", { class: "badge alarm", text: alarms.join(", ") })
                                  : el("span", { class: "na", text: "none" })));
    if (s.name === state.selected) tr.classList.add("selected");
    body.append(tr);
  }
}
function select(name) {
  if (state.selected !== name) {
    state.selected = name;
    history.replaceState(null, "", "#" + encodeURIComponent(name));
    dropPlots("");
    state.tick = 0;
    state.units = null;
  }
  refresh();
}

// ------------------------------------------------------------------ estimate and alarms
function headline(est) {
  // the headline: `parameters` (possibly from `best`, see estimate_source); `best` beside it
  return { params: est.parameters || {}, source: est.estimate_source || "–", best: get(est, "best", "parameters") || {} };
}
function renderEstimate(est) {
  const box = document.getElementById("estimate-table");
  const { params, source, best } = headline(est);
  const names = Object.keys(params).length ? Object.keys(params) : Object.keys(best);
  if (!names.length) { box.replaceChildren(na("no estimate yet (" + (est.state || "starting") + ")")); return; }
  const units = est.parameter_units || state.units || {};
  const t = el("table", {}, el("tr", {}, ...["parameter", "unit", "value", "95 % interval", "source", "best (output error)", "best 95 %"].map(h => el("th", { text: h }))));
  for (const p of names) {
    const s = params[p] || {}; const b = best[p] || {};
    const v = s.mean ?? s.value; const ci = s.ci95 || [];
    t.append(el("tr", {}, el("td", { text: p }), el("td", { text: units[p] || "–" }), el("td", { class: "num", text: fmt(v) }),
      el("td", { class: "num", text: ci.length === 2 ? `${fmt(ci[0])} … ${fmt(ci[1])}` : "–" }),
      el("td", { text: s.source || source }),
      el("td", { class: "num", text: fmt(b.value ?? b.mean) }),
      el("td", { class: "num", text: Array.isArray(b.ci95) ? `${fmt(b.ci95[0])} … ${fmt(b.ci95[1])}` : "–" })));
  }
  box.replaceChildren(t);
  const sum = document.getElementById("system-summary");
  const secs = est.seconds_per_epoch;
  sum.textContent = `state ${est.state || "–"} · epoch ${est.epoch ?? "–"}` +
    (est.converged ? ` · converged at ${est.converged_at ?? "?"}` : " · not converged") +
    (typeof secs === "number" && secs > 0 ? ` · ${fmt(1 / secs, 3)} epochs/s` : "") +
    ` · snapshot ${localTime(est.time)}` +
    (est.error ? ` · error: ${est.error}` : "");
}
/** The validation test's verdict when the service publishes one (``validation`` or
 * ``best.validation`` with a boolean ``accepted``: T statistic, p-value); else null. */
function verdictOf(est) {
  for (const v of [get(est, "validation"), get(est, "best", "validation"), get(est, "verdict")]) {
    if (v && typeof v === "object" && typeof v.accepted === "boolean") return v;
    if (v && typeof v === "object" && (v.verdict === "accepted" || v.verdict === "rejected"))
      return Object.assign({}, v, { accepted: v.verdict === "accepted", statistic: v.T });  // the service's estimate
  }
  return null;
}
function renderVerdict(est) {
  const box = document.getElementById("verdict");
  const v = verdictOf(est);
  if (!v) { box.hidden = true; box.replaceChildren(); return; }
  box.hidden = false;
  const stats = [typeof v.statistic === "number" ? `T = ${fmt(v.statistic, 3)}` : null,
                 typeof v.p_value === "number" ? `p = ${fmt(v.p_value, 2)}` : null].filter(Boolean).join(", ");
  box.className = "verdict " + (v.accepted ? "accepted" : "rejected");
  box.replaceChildren(v.accepted
    ? el("span", { text: `Validation: model accepted${stats ? " (" + stats + ")" : ""}` })
    : el("span", {}, el("strong", { text: "Model rejected by the validation test" + (stats ? ` (${stats})` : "") + ": " }),
        document.createTextNode(v.next || v.hint || "it does not explain the validation records; do not use these parameters yet. "),
        "Try ", el("code", { text: "siva diagnose" }), " (or the Diagnosis panel below) to find what the model is missing."));
}
function alarmState(a) { return a.state || (a.active === false ? "cleared" : "active"); }
function renderAlarms(drift) {
  const box = document.getElementById("alarms");
  const alarms = (drift && drift.alarms) || [];
  if (!alarms.length) { box.replaceChildren(na(drift ? "no alarm" : undefined)); return; }
  const t = el("table", {}, el("tr", {}, ...["quantity", "state", "change", "raised at record", "raised (local time)", "message"].map(h => el("th", { text: h }))));
  for (const a of alarms.slice().reverse()) {
    const st = alarmState(a);
    t.append(el("tr", {}, el("td", { text: (a.parameter || "–") + unitOf(a.parameter) }),
      el("td", {}, el("span", { class: "badge " + st, text: st })),
      el("td", { class: "num", text: typeof a.change_rel === "number" ? (a.change_rel > 0 ? "+" : "") + (100 * a.change_rel).toFixed(1) + " %" : "–" }),
      el("td", { class: "num", text: String(a.raised_index ?? "–") }),
      el("td", { text: localTime(a.raised_time) }),
      el("td", { text: a.message || "" })));
  }
  box.replaceChildren(t);
}

// ------------------------------------------------------------------ traces over time
function historyOf(drift) {
  // x axes are wall-clock time (local): a snapshot without a time cannot be placed
  const h = (drift && (drift.history || drift.snapshots)) || [];
  return h.filter(e => e && typeof e.time === "number" && isFinite(e.time));
}
function unitOf(p) { const u = (state.units || {})[p]; return u ? ` [${u}]` : ""; }
/** Alarm times [s] (raised) for the markers of quantity p. */
function alarmTimes(alarms, p) {
  return (alarms || []).filter(a => a.parameter === p).map(a => a.raised_time).filter(v => typeof v === "number");
}
function renderParamTraces(drift, est) {
  const box = document.getElementById("param-plots");
  const hist = historyOf(drift);
  if (hist.length < 2) { dropPlots("param:"); box.replaceChildren(na("not yet available (fewer than 2 snapshots)")); return; }
  if (box.querySelector(".na")) box.replaceChildren();
  const names = Object.keys(Object.assign({}, ...hist.map(e => e.parameters || {}), ...hist.map(e => e.ensemble || {})));
  const alarms = (drift.alarms || []);
  const ref = get(drift, "reference", "parameters") || {};
  const x = hist.map(e => e.time);
  const w = plotWidth(box, names.length > 1 ? 0.33 : 1);
  for (const p of names) {
    const id = "param:" + p;
    let holder = document.getElementById("holder-" + id);
    if (!holder) { holder = el("div", { id: "holder-" + id }); box.append(holder); }
    const mean = hist.map(e => numOr(get(e, "parameters", p, "mean") ?? get(e, "parameters", p, "value")));
    const lo = hist.map(e => numOr(get(e, "parameters", p, "ci95", 0)));
    const hi = hist.map(e => numOr(get(e, "parameters", p, "ci95", 1)));
    const ens = hist.map(e => numOr(get(e, "ensemble", p, "mean") ?? get(e, "ensemble", p)));
    const elo = hist.map(e => numOr(get(e, "ensemble", p, "ci95", 0)));
    const ehi = hist.map(e => numOr(get(e, "ensemble", p, "ci95", 1)));
    const band = get(ref, p, "band") || [];
    const rlo = x.map(() => numOr(band[0])), rhi = x.map(() => numOr(band[1]));
    const marks = alarmTimes(alarms, p);
    const opts = {
      title: p + unitOf(p), width: w, height: 200, plugins: [markersPlugin(marks)],
      scales: { x: { time: true } },
      axes: [{ label: "time (local)" }, { size: 70 }],
      series: [{ label: "time" },
        { label: "headline", stroke: "#ff7f0e", width: 1.5 },
        { label: "95 % lo", stroke: "rgba(255,127,14,0.4)", width: 0.5 },
        { label: "95 % hi", stroke: "rgba(255,127,14,0.4)", width: 0.5 },
        { label: "ensemble", stroke: "#1f77b4", width: 1 },
        { label: "ens. 95 % lo", stroke: "rgba(31,119,180,0.4)", width: 0.5 },
        { label: "ens. 95 % hi", stroke: "rgba(31,119,180,0.4)", width: 0.5 },
        { label: "ref lo", stroke: "#555", dash: [4, 4], width: 1 },
        { label: "ref hi", stroke: "#555", dash: [4, 4], width: 1 }],
      bands: [{ series: [3, 2], fill: "rgba(255,127,14,0.18)" }, { series: [6, 5], fill: "rgba(31,119,180,0.15)" }],
    };
    upsertPlot(id, holder, opts, [x, mean, lo, hi, ens, elo, ehi, rlo, rhi]);
  }
}
function numOr(v) { return typeof v === "number" && isFinite(v) ? v : null; }

function renderModal(drift) {
  const hist = historyOf(drift);
  for (const [key, boxId, title] of [["frequency_hz", "freq-plot", "f"], ["damping_ratio", "damping-plot", "ζ"]]) {
    const box = document.getElementById(boxId);
    const rows = hist.map(e => get(e, "modal", key) || get(e, "modal_estimate", key));
    const nModes = Math.max(0, ...rows.map(r => (Array.isArray(r) ? r.length : 0)));
    if (hist.length < 2 || nModes === 0) { dropPlots("modal:" + key); box.replaceChildren(na("not yet available")); continue; }
    if (box.querySelector(".na")) box.replaceChildren();
    const x = hist.map(e => e.time);
    const series = [{ label: "time" }], data = [x];
    for (let m = 0; m < nModes; m++) {
      series.push({ label: `${title}${m + 1}`, stroke: COLORS[m % COLORS.length], width: 1.5 });
      data.push(rows.map(r => (Array.isArray(r) ? numOr(r[m]) : null)));
    }
    upsertPlot("modal:" + key, box, { width: plotWidth(box), height: 200, scales: { x: { time: true } },
      axes: [{ label: "time (local)" }, { size: 60 }], series }, data);
  }
}

// ------------------------------------------------------------------ validation score
function renderValidation(est) {
  const box = document.getElementById("validation");
  const v = get(est, "validation") || {};
  const disc = get(est, "discriminator", "records") || {};
  const rows = [];
  for (const of of ["headline", "ensemble"]) {
    for (const r of (get(v, of, "per_record") || [])) rows.push([of, r]);
  }
  if (!rows.length) {
    box.replaceChildren(na(v.reason || "not yet available"));
    return;
  }
  const head = el("p", {}, el("span", { class: "badge " + (v.verdict === "rejected" ? "confirmed" : "cleared"),
    text: `model ${v.verdict}` }), el("span", { text: `  T = ${fmt(v.T, 3)}, p = ${fmt(v.p_value, 3)} (${v.of})` }));
  const t = el("table", {}, el("tr", {}, ...["of", "record", "T", "p-value", "verdict", "loss_D (discriminator)"].map(h => el("th", { text: h }))));
  for (const [of, r] of rows) {
    t.append(el("tr", {}, el("td", { text: of }), el("td", { text: r.record }),
      el("td", { class: "num", text: fmt(r.T, 3) }), el("td", { class: "num", text: fmt(r.p_value, 3) }),
      el("td", { text: r.verdict || r.error || "–" }),
      el("td", { class: "num", text: fmt(get(disc, r.record, "loss_d"), 4) })));
  }
  box.replaceChildren(head, t);
}

// ------------------------------------------------------------------ latest record
function renderLatest(lr) {
  const box = document.getElementById("latest-plots");
  const specBox = document.getElementById("spectrum-plots");
  const cwtBox = document.getElementById("cwt-plots");
  const meta = document.getElementById("latest-meta");
  if (!lr || !lr.available) {
    const why = (lr && lr.reason) || "not yet available";
    for (const b of [box, specBox, cwtBox]) b.replaceChildren(na(why));
    dropPlots("latest:"); meta.textContent = "";
    return;
  }
  for (const b of [box, specBox, cwtBox]) if (b.querySelector(".na")) b.replaceChildren();
  const rec = lr.record || {};
  if (lr.parameter_units) state.units = lr.parameter_units;
  meta.textContent = `${rec.id || "?"} (${rec.role || "?"}, received ${typeof rec.received_at === "number" ? localTime(rec.received_at) : (rec.received_at_iso || "?")}), ` +
    `simulated with ${lr.parameters_source || "?"}` + (lr.diverged ? " — the simulation diverged" : "");
  const dofs = Object.keys(lr.dofs || {});
  for (const d of dofs) {
    const D = lr.dofs[d];
    const h1 = holder(box, "latest:resp:" + d);
    upsertPlot("latest:resp:" + d, h1, { title: `${d}: displacement [mm]` + (typeof D.nmse === "number" ? ` (NMSE ${fmt(D.nmse, 3)})` : ""),
      width: plotWidth(box, 0.5), height: 220, scales: { x: { time: false } }, axes: [{ label: "time [s]" }, { size: 60 }],
      series: [{ label: "t" }, { label: "measured", stroke: "#000", width: 1 }, { label: "simulated", stroke: "#d62728", width: 1 }] },
      [lr.t, D.measured, D.simulated]);
    const h2 = holder(box, "latest:res:" + d);
    upsertPlot("latest:res:" + d, h2, { title: `${d}: residual measured − simulated [mm]`,
      width: plotWidth(box, 0.5), height: 220, scales: { x: { time: false } }, axes: [{ label: "time [s]" }, { size: 60 }],
      series: [{ label: "t" }, { label: "residual", stroke: "#9467bd", width: 1 }] }, [lr.t, D.residual]);
    const sp = get(D, "spectrum") || {};
    const pos = a => (a || []).map(v => (typeof v === "number" && v > 0 ? v : null));
    const h3 = holder(specBox, "latest:spec:" + d);
    upsertPlot("latest:spec:" + d, h3, { title: `${d}`, width: plotWidth(specBox), height: 200,
      scales: { x: { time: false }, y: { distr: 3, range: safeLog } },
      axes: [{ label: "frequency [Hz]" }, { size: 70 }], plugins: [markersPlugin(lr.modes_hz || [], "#2ca02c")],
      series: [{ label: "Hz" }, { label: "measured", stroke: "#000", width: 1 }, { label: "simulated", stroke: "#d62728", width: 1 }] },
      [lr.spectrum_hz, pos(sp.measured), sp.simulated ? pos(sp.simulated) : lr.spectrum_hz.map(() => null)]);
    drawCwtRow(cwtBox, d, D.cwt || {}, lr.cwt_hz || [], lr.cwt_t || []);
  }
}
function holder(box, id) {
  let h = document.getElementById("holder-" + id);
  if (!h) { h = el("div", { id: "holder-" + id }); box.append(h); }
  return h;
}
/** CWT magnitudes (rows = frequencies, low first) as a jet-coloured canvas image. */
function drawCwtRow(box, dof, cw, freqs, times) {
  const id = "cwt-" + dof;
  let row = document.getElementById(id);
  if (!row) { row = el("div", { id, class: "cwt-row" }); box.append(row); }
  row.replaceChildren();
  for (const label of ["measured", "simulated"]) {
    const m = cw[label];
    if (!Array.isArray(m) || !m.length) { row.append(el("figure", {}, na(`${dof} ${label}: not available`))); continue; }
    const nf = m.length, nt = m[0].length;
    const c = el("canvas", { class: "cwt", width: nt, height: nf });
    c.style.width = Math.min(360, Math.floor((box.clientWidth || 700) / 2) - 10) + "px"; c.style.height = "160px";
    const ctx = c.getContext("2d"); const img = ctx.createImageData(nt, nf);
    for (let i = 0; i < nf; i++) for (let j = 0; j < nt; j++) {
      const [r, g, b] = jet(m[nf - 1 - i][j]); const o = 4 * (i * nt + j);
      img.data[o] = r; img.data[o + 1] = g; img.data[o + 2] = b; img.data[o + 3] = 255;
    }
    ctx.putImageData(img, 0, 0);
    const cap = `${dof} ${label}: ${fmt(freqs[0], 3)}–${fmt(freqs[freqs.length - 1], 3)} Hz (log axis), ` +
      `${fmt(times[0], 3)}–${fmt(times[times.length - 1], 3)} s`;
    row.append(el("figure", {}, c, el("figcaption", { text: cap })));
  }
}
function jet(v) {
  const x = Math.max(0, Math.min(1, v || 0));
  const r = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * x - 3)));
  const g = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * x - 2)));
  const b = Math.max(0, Math.min(1, 1.5 - Math.abs(4 * x - 1)));
  return [Math.round(255 * r), Math.round(255 * g), Math.round(255 * b)];
}

// ------------------------------------------------------------------ diagnosis (optional)
async function diagnosisPath() {
  // asked of the schema once, so a service without the endpoint causes no 404 in the console
  if (!state.openapiChecked) {
    state.openapiChecked = true;
    try {
      const api = await getJSON("/openapi.json");
      state.diagnosisPath = Object.keys(api.paths || {}).find(p => /^\/v1\/systems\/\{[^}]+\}\/diagnosis$/.test(p)) || null;
    } catch (e) { state.diagnosisPath = null; }
  }
  return state.diagnosisPath;
}
async function renderDiagnosis(name) {
  const panel = document.getElementById("diagnosis-panel");
  const path = await diagnosisPath();
  if (!path) { panel.hidden = true; return; }
  let body = null;
  try {
    const r = await fetch(path.replace(/\{[^}]+\}/, encodeURIComponent(name)));
    if (r.status === 200) body = await r.json();
  } catch (e) { body = null; }
  if (!body) { panel.hidden = true; return; }
  panel.hidden = false;
  const box = document.getElementById("diagnosis");
  const parts = [];
  const summary = body.summary || body.message || body.verdict;
  if (summary) parts.push(el("p", { text: typeof summary === "string" ? summary : JSON.stringify(summary) }));
  const items = body.findings || body.candidates || body.effects || body.ranking;
  if (Array.isArray(items) && items.length) {
    const ul = el("ul");
    for (const it of items.slice(0, 10)) ul.append(el("li", { text: typeof it === "string" ? it : (it.message || it.name || it.effect || JSON.stringify(it)) }));
    parts.push(ul);
  }
  parts.push(el("details", {}, el("summary", { text: "raw diagnosis" }), el("pre", { text: JSON.stringify(body, null, 2) })));
  box.replaceChildren(...parts);
}

// ------------------------------------------------------------------ the loop
async function refresh() {
  const status = document.getElementById("status");
  try {
    const fleet = await getJSON("/v1/systems");
    const systems = fleet.systems || [];
    if (!state.selected && systems.length) {
      const fromHash = decodeURIComponent(location.hash.slice(1));
      state.selected = systems.some(s => s.name === fromHash) ? fromHash : systems[0].name;
    }
    renderFleet(systems);
    const sysSec = document.getElementById("system");
    const sel = systems.find(s => s.name === state.selected);
    if (!sel || sel.state === "invalid_spec") { sysSec.hidden = true; }
    else {
      sysSec.hidden = false;
      document.getElementById("system-title").textContent = sel.name;
      const name = encodeURIComponent(sel.name);
      if (!state.units) {  // units before the first table and plot titles (once per system)
        const info = await getJSON(`/v1/systems/${name}`).catch(() => ({}));
        state.units = info.parameter_units || {};
      }
      const [est, drift] = await Promise.all([getJSON(`/v1/systems/${name}/estimate`),
                                              getJSON(`/v1/systems/${name}/drift`).catch(() => null)]);
      renderVerdict(est);
      renderEstimate(est); renderAlarms(drift); renderParamTraces(drift, est); renderModal(drift);
      renderValidation(est);
      if (state.tick % LATEST_EVERY === 0) {
        const lr = await getJSON(`/v1/systems/${name}/latest-record`).catch(e => ({ available: false, reason: String(e.message || e) }));
        renderLatest(lr);
        await renderDiagnosis(sel.name);
      }
    }
    state.tick++;
    status.classList.remove("error");
    status.textContent = `live · ${systems.length} system(s) · updated ${new Date().toLocaleTimeString()}`;
  } catch (e) {
    status.classList.add("error");
    status.textContent = "cannot reach the service: " + (e.message || e) + " (retrying)";
  }
}
let timer = null;
async function loop() { await refresh(); timer = setTimeout(loop, POLL_MS); }
window.addEventListener("resize", () => {
  for (const p of Object.values(state.plots)) {
    const box = p.u.root.parentElement && p.u.root.parentElement.parentElement;
    if (box) p.u.setSize({ width: plotWidth(box, p.u.root.parentElement.id.includes("param:") ? 0.33 : (p.u.root.parentElement.id.includes(":resp:") || p.u.root.parentElement.id.includes(":res:") ? 0.5 : 1)), height: p.u.height });
  }
});
window.sivaDashboard = state;  // for the browser test and the curious
loop();
