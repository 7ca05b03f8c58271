// tuner's page. Plain JavaScript, no library. The form's state lives in the URL (?plant=...&dt=...&structure=...;
// a default design limit that is lifted is written empty, filter_n_max=; run=1 runs the tune on open,
// run=tradeoff the trade-off curve, id=ID shows a stored result); the API's 422 details are shown at the field
// their loc names; the API key is kept in sessionStorage and sent as X-API-Key. The trade-off curve is an inline
// SVG drawn here (DOM calls only: nothing inline for the CSP to refuse).
"use strict";

const CONFIG = JSON.parse(document.getElementById("config").textContent);
const $ = (sel, root = document) => root.querySelector(sel);
const $$ = (sel, root = document) => Array.from(root.querySelectorAll(sel));
const form = $("#tune-form");
const SPEC = Object.keys(CONFIG.spec_defaults);
const NULLABLE = new Set(CONFIG.spec_nullable);  // an empty input sends null (lifts a default limit)
const LIMITS = CONFIG.default_limits;

// the optional limits' inputs: one per limit of the registry (tuner.limits, through the page's configuration)
for (const l of CONFIG.limits) {
  const row = l.row === "speed" ? $("#speed-knob") : $("#optional-limits");
  const lab = document.createElement("label");
  lab.className = "field";
  lab.dataset.loc = `spec.${l.field}`;
  lab.title = l.help;
  const inp = document.createElement("input");
  Object.assign(inp, { type: "number", name: l.field, id: l.field, step: "any", placeholder: "none" });
  if (l.min !== undefined) inp.min = String(l.min);
  const err = document.createElement("span");
  err.className = "err";
  lab.append(`${l.label} `, inp, err);
  row.insertBefore(lab, row.querySelector(".hint"));
}
$("#effort").replaceChildren(...CONFIG.efforts.map((e) => new Option(e, e, e === "default", e === "default")));
const ROLL = { plant: "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)", dt: "0.04", structure: "pid_z" };
const HIST = 10;
const KEY = "tuner.apiKey";
const state = { id: null, running: null, urls: [], histOffset: 0, exportFormat: "c", curve: null, ident: null };

// -- talking to the service ----------------------------------------------------------------------

async function api(path, { method = "GET", json, signal } = {}) {
  const headers = {};
  const key = sessionStorage.getItem(KEY);
  if (key) headers["X-API-Key"] = key;
  let body;
  if (json !== undefined) { headers["Content-Type"] = "application/json"; body = JSON.stringify(json); }
  const r = await fetch(path, { method, headers, body, signal });
  if (r.status === 401) keyState("the service needs an API key (missing or wrong): enter it above", true);
  return r;
}

async function answer(r) {
  const type = r.headers.get("content-type") || "";
  if (type.includes("json")) return r.json();
  return { detail: `${r.status} ${r.statusText}: ${(await r.text()).slice(0, 300)}` };
}

// an error's detail as sentences: a string as it is, FastAPI's list of {loc, msg} as "where: what; ...", never raw JSON
function detailText(d) {
  const x = d?.detail ?? d;
  if (typeof x === "string") return x;
  if (Array.isArray(x)) {
    return x.map((it) => {
      if (typeof it === "string") return it;
      const loc = (it?.loc || []).filter((p, i) => !(i === 0 && ["body", "query", "path"].includes(p))).join(".");
      return (loc ? `${loc}: ` : "") + (it?.msg ?? "invalid");
    }).join("; ");
  }
  if (x && typeof x === "object") return String(x.message ?? x.msg ?? "the service refused the request");
  return String(x ?? "no answer");
}

// a failed request in words: the service's sentences; its status only when it failed (5xx) or said nothing
function errorText(r, d) {
  const text = detailText(d);
  return r.status >= 500 ? `the service failed (HTTP ${r.status}): ${text}` : text;
}

function keyState(text, bad = false) {
  const el = $("#key-state");
  el.textContent = text;
  el.className = bad ? "err" : "hint";
  if (bad) $("#api-key").focus();
}

// -- numbers -------------------------------------------------------------------------------------

function fmt(v) {
  if (v === "Infinity" || v === Infinity) return "∞";
  if (v === "-Infinity" || v === -Infinity) return "−∞";
  if (v === "NaN" || v === null || v === undefined || Number.isNaN(v)) return "—";
  if (typeof v === "boolean") return v ? "yes" : "no";
  if (typeof v === "number") return Number.isInteger(v) && Math.abs(v) < 1e6 ? String(v) : String(Number(v.toPrecision(4)));
  return String(v);
}

function label(name) {
  const units = [["_rad_s", " [rad/s]"], ["_deg", " [deg]"], ["_db", " [dB]"], ["_pct", " [%]"], ["_s", " [s]"]];
  let unit = "";
  for (const [suffix, u] of units) {
    if (name.endsWith(suffix)) { name = name.slice(0, -suffix.length); unit = u; break; }
  }
  const short = { ms: "Ms", mt: "Mt", mks: "Mks", filter_n: "filter N = Td/Tf", filter_tf_s: "filter Tf ≥ dt/π", control_peak: "control peak |u|" };
  return (short[name] || name.replaceAll("_", " ")) + unit;
}

const OPS = { ">=": "≥", "<=": "≤", "==": "=", "<": "<", ">": ">" };

// -- the form and the URL ------------------------------------------------------------------------

function field(name) { return form.elements.namedItem(name); }

function mode() { return form.elements.pmode.value; }

function setMode(m) {
  form.elements.pmode.value = m;
  for (const el of $$(".mode", form)) el.hidden = el.dataset.mode !== m;
}

// a spec value as the form holds it; gain_variation is a checkbox: on for "auto" (or a range), off for null
function specValue(k, v) {
  if (k === "gain_variation") return v === null ? "0" : "1";
  return v === null ? "" : typeof v === "boolean" ? (v ? "1" : "0") : String(v);
}

function defaults() {
  const d = { var: "s", budget: String(CONFIG.default_budget_s), seed: "0", effort: "default", y: CONFIG.tradeoff.y[0],
              points: String(CONFIG.tradeoff.default_points) };
  for (const k of SPEC) d[k] = specValue(k, CONFIG.spec_defaults[k]);
  return d;
}

const NAMES = ["plant", "num", "den", "var", "delay", "dt", "structure", ...SPEC, "budget", "seed", "effort", "y",
               "points"];

function readForm() {
  const out = {};
  for (const n of NAMES) {
    const el = field(n);
    if (!el) continue;  // a spec field the form does not offer (the service's default applies)
    out[n] = el.type === "checkbox" ? (el.checked ? "1" : "0") : el.value.trim();
  }
  out.plants = field("plants").value.split("\n").map((s) => s.trim()).filter(Boolean);
  return out;
}

function writeForm(values) {
  const d = defaults();
  for (const n of NAMES) {
    const el = field(n);
    if (!el) continue;
    const v = values[n] ?? d[n] ?? "";
    if (el.type === "checkbox") el.checked = v === "1" || v === "true" || v === true;
    else el.value = v;
  }
  field("plants").value = (values.plants || []).join("\n");
  $("#robust").open = (values.plants || []).length > 0;
  setMode(values.num || values.den ? "coeffs" : "expr");
  syncSliders();
  structureHint();
  syncThesis();
}

// The "pure thesis spec" box: checked when every default design limit is lifted; checking it lifts them all,
// unchecking it puts the defaults back.
function lifted(k) {
  const el = field(k);
  return el.type === "checkbox" ? !el.checked : el.value.trim() === "";
}

function syncThesis() { $("#thesis").checked = LIMITS.every(lifted); }

function setThesis(on) {
  const d = defaults();
  for (const k of LIMITS) {
    const el = field(k);
    if (el.type === "checkbox") el.checked = on ? false : d[k] === "1";
    else el.value = on ? "" : d[k];
  }
}

function formParams(extra = {}) {
  const f = readForm();
  const d = defaults();
  const p = new URLSearchParams();
  const m = mode();
  for (const n of NAMES) {
    if ((n === "plant" && m !== "expr") || ((n === "num" || n === "den" || n === "var") && m !== "coeffs")) continue;
    if (!(n in f)) continue;  // (no input for it on the form)
    // empty where the default is not (a lifted filter_n_max) is state too: written as "filter_n_max="
    if (f[n] !== (d[n] ?? "")) p.set(n, f[n]);
  }
  for (const x of f.plants) p.append("plants", x);
  for (const [k, v] of Object.entries(extra)) if (v !== null && v !== undefined) p.set(k, v);
  return p;
}

function fromParams(p) {
  const v = {};
  for (const n of NAMES) if (p.has(n)) v[n] = p.get(n);
  v.plants = p.getAll("plants");
  return v;
}

function syncURL(extra = {}) {
  const q = formParams({ identification: identPlant()?.id, ...extra }).toString();
  history.replaceState(null, "", q ? `/?${q}` : "/");
}

function syncSliders() {
  for (const r of $$("input[type=range][data-sync]", form)) {
    const v = Number(field(r.dataset.sync).value);
    if (field(r.dataset.sync).value !== "" && Number.isFinite(v)) r.value = v;
  }
}

// every registered firmware (the service's registry): its law, its parameter file's format and its export tab
const FIRMWARE = new Set(CONFIG.firmwares.map((f) => f.structure));
const PARAM_FORMATS = new Set(CONFIG.firmwares.map((f) => f.format));
for (const f of CONFIG.firmwares) {  // a tab per firmware's parameter file, shown for that law's results
  const b = document.createElement("button");
  b.type = "button";
  b.dataset.format = f.format;
  b.hidden = true;
  b.title = `the parameter file its ground station loads: ${f.files}`;
  b.textContent = `${f.title} .${f.suffix}`;
  $("#export-name").closest("label").before(b);
}

function vehicleRow() { $("#vehicle-row").hidden = !FIRMWARE.has(field("structure").value); }

function structureHint() {
  const s = CONFIG.structures.find((x) => x.name === field("structure").value);
  $("#structure-params").textContent = s ? `gains: ${s.params.join(", ")}${s.discrete_only ? " (needs dt)" : ""}` : "";
}

// -- errors at their fields ----------------------------------------------------------------------

function clearErrors(root) {
  for (const el of $$(".invalid", root)) el.classList.remove("invalid");
  for (const el of $$(".err", root)) el.textContent = "";
  for (const el of $$(".err-general", root)) { el.textContent = ""; el.hidden = true; }
}

function errorSlot(el) {
  let slot = el.querySelector(":scope > .err");
  if (!slot) { slot = document.createElement("div"); slot.className = "err"; el.append(slot); }
  return slot;
}

// Each item {loc, msg}: shown at the element whose data-loc is the longest prefix of loc (without "body").
function showErrors(root, items, general) {
  const targets = $$("[data-loc]", root);
  const left = [];
  for (const it of items) {
    const key = (it.loc || []).filter((x, i) => !(i === 0 && x === "body")).join(".");
    let best = null, bestLen = -1;
    for (const el of targets) {
      for (const t of el.dataset.loc.split(" ")) {
        if ((key === t || key.startsWith(t + ".")) && t.length > bestLen && !el.closest("[hidden]")) { best = el; bestLen = t.length; }
      }
    }
    if (best) {
      best.classList.add("invalid");
      const slot = errorSlot(best);
      slot.textContent = (slot.textContent ? slot.textContent + "; " : "") + it.msg;
    } else left.push(`${key || "request"}: ${it.msg}`);
  }
  if (left.length) { general.textContent = left.join("\n"); general.hidden = false; }
  const first = $(".invalid input, .invalid select, .invalid textarea", root) || $(".invalid", root);
  if (first && first.focus) first.focus();
}

function showGeneral(el, text) { el.textContent = text; el.hidden = false; }

// -- building the request ------------------------------------------------------------------------

function number(text, loc, errs, { int = false } = {}) {
  if (text === "") return undefined;
  const v = Number(text);
  if (!Number.isFinite(v) || (int && !Number.isInteger(v))) { errs.push({ loc, msg: `not ${int ? "an integer" : "a number"}: ${text}` }); return undefined; }
  return v;
}

function numbers(text, loc, errs) {
  const parts = text.split(/[\s,;]+/).filter(Boolean);
  if (!parts.length) { errs.push({ loc, msg: "give the coefficients, highest power first" }); return undefined; }
  const out = [];
  parts.forEach((t, i) => {
    const v = Number(t);
    if (Number.isFinite(v)) out.push(v); else errs.push({ loc: [...loc, i], msg: `coefficient ${i + 1} is not a number: ${t}` });
  });
  return out;
}

// The identification the form's plant came from (POST /identify, or identification=ID in the URL): sent with a tune
// as identification_id, so the result is judged on the airframe's measured response and the identification's rating
// too; forgotten as soon as the plant in the form is edited (or more plants are given).
function identPlant() {
  const id = state.ident;
  if (!id) return null;
  const f = readForm();
  return mode() === "coeffs" && f.num === id.num && f.den === id.den && f.delay === id.delay && !f.plants.length
    ? id : null;
}

function rememberIdent(id) {
  const f = readForm();
  state.ident = { id, num: f.num, den: f.den, delay: f.delay };
}

function tuneBody({ identification = false } = {}) {
  const f = readForm();
  const errs = [];
  const dt = number(f.dt, ["body", "dt"], errs);
  const delay = number(f.delay, ["body", "plant", "delay"], errs);
  const plant = {};
  if (mode() === "csv") errs.push({ loc: ["body", "input"], msg: "identify the log first (or enter the plant)" });
  if (mode() === "coeffs") {
    plant.num = numbers(f.num, ["body", "plant", "num"], errs);
    plant.den = numbers(f.den, ["body", "plant", "den"], errs);
    if (f.var === "z") plant.dt = dt ?? null;
  } else if (f.plant) {
    plant.expr = f.plant;
    if (/z/.test(f.plant)) plant.dt = dt ?? null;
  }
  if (delay !== undefined) plant.delay = delay;
  const spec = {};
  for (const k of SPEC) {
    const el = field(k);
    if (!el) continue;
    if (k === "gain_variation") spec[k] = el.checked ? "auto" : null;
    else if (el.type === "checkbox") spec[k] = el.checked;
    else if (el.tagName === "SELECT") spec[k] = f[k];
    else {
      const v = number(f[k], ["body", "spec", k], errs);
      if (v !== undefined) spec[k] = v;
      else if (f[k] === "" && NULLABLE.has(k)) spec[k] = null;  // none: JSON null, not the server's default
    }
  }
  const body = { plant, dt: dt ?? null, structure: f.structure, spec,
                 options: { seed: number(f.seed, ["body", "options", "seed"], errs, { int: true }) ?? 0 } };
  const ident = identification ? identPlant() : null;
  if (ident) { delete body.plant; body.identification_id = ident.id; }
  if (FIRMWARE.has(f.structure)) {  // a firmware law: the vehicle's parameters, if given (else its defaults)
    const text = $("#vehicle-from-log").checked && csv.params ? csv.params : state.vehicleText;
    if (text) body.vehicle = { params: text, axis: $("#vehicle-axis").value };
  }
  const budget = number(f.budget, ["body", "options", "time_budget_s"], errs);
  if (budget !== undefined) body.options.time_budget_s = budget;
  if (f.effort && f.effort !== "default") body.options.effort = f.effort;
  if (f.plants.length) {
    body.plants = f.plants.map((e) => {
      const p = { expr: e };
      if (/z/.test(e)) p.dt = dt ?? null;
      if (delay !== undefined) p.delay = delay;
      return p;
    });
  }
  return { body, errs, budget: budget ?? CONFIG.default_budget_s };
}

// -- running a tune ------------------------------------------------------------------------------

function busy(on, budget = 0, what = "tuning") {
  $("#run-btn").disabled = on;
  $("#tradeoff-btn").disabled = on;
  $("#cancel-btn").hidden = !on;
  const el = $("#progress");
  clearInterval(state.ticker);
  if (!on) return;
  const t0 = performance.now();
  el.innerHTML = `<span class="spinner"></span><span id="elapsed">${what}… 0.0 s</span> <progress></progress>`;
  const bar = $("progress", el);
  bar.max = budget;
  state.ticker = setInterval(() => {
    const s = (performance.now() - t0) / 1000;
    $("#elapsed").textContent = `${what}… ${s.toFixed(1)} s of a ${fmt(budget)} s budget`;
    bar.value = Math.min(s, budget);
  }, 100);
}

// POST the form to path (with extra fields in the body); d => the answer when it is a 200, else null.
async function post(path, extra, what, opts = {}) {
  clearErrors(form);
  const { body, errs, budget } = tuneBody(opts);
  if (errs.length) { showErrors(form, errs, $("#form-error")); return null; }
  Object.assign(body, extra(errs));
  if (errs.length) { showErrors(form, errs, $("#form-error")); return null; }
  syncURL();
  const ctl = new AbortController();
  state.running = ctl;
  busy(true, budget, what);
  try {
    const r = await api(path, { method: "POST", json: body, signal: ctl.signal });
    const d = await answer(r);
    busy(false);
    if (r.status === 422 && Array.isArray(d.detail)) {
      $("#progress").textContent = "the input needs a change (see the marked fields)";
      showErrors(form, d.detail, $("#form-error"));
      return null;
    }
    if (!r.ok) { $("#progress").textContent = ""; showGeneral($("#form-error"), errorText(r, d)); return null; }
    return d;
  } catch (e) {
    busy(false);
    if (e.name === "AbortError") $("#progress").textContent = "cancelled: the server stops the solve";
    else showGeneral($("#form-error"), `could not reach the service: ${e.message}`);
    return null;
  } finally {
    state.running = null;
  }
}

async function runTune() {
  const d = await post("/tune", () => ({}), "tuning", { identification: true });
  if (!d) return;
  $("#progress").textContent = `done in ${fmt(d.solver?.wall_time_s)} s`;
  showResult(d);
  syncURL({ id: d.id });
  loadHistory(0);
}

// -- the trade-off curve -------------------------------------------------------------------------

async function runTradeoff() {
  const f = readForm();
  const d = await post("/tradeoff", (errs) => ({
    y: f.y, points: number(f.points, ["body", "points"], errs, { int: true }) ?? CONFIG.tradeoff.default_points,
  }), "computing the curve");
  if (!d) return;
  const n = d.points.length;
  $("#progress").textContent = `${n} verified point${n === 1 ? "" : "s"} in ${fmt(d.wall_time_s)} s`;
  showCurve(d);
  syncURL();
}

// The curve's <svg> is in the page (the HTML parser gives it the SVG namespace, which its children take).
function svg(tag, attrs = {}, parent = null, text = null) {
  const el = document.createElementNS($("#curve").namespaceURI, tag);
  for (const [k, v] of Object.entries(attrs)) el.setAttribute(k, String(v));
  if (text !== null) el.textContent = text;
  if (parent) parent.append(el);
  return el;
}

// About five round ticks covering [lo, hi].
function ticks(lo, hi) {
  if (!(hi > lo)) { const pad = Math.abs(lo) * 0.1 || 1; lo -= pad; hi += pad; }
  const raw = (hi - lo) / 5;
  const mag = 10 ** Math.floor(Math.log10(raw));
  const step = [1, 2, 2.5, 5, 10].map((m) => m * mag).find((x) => x >= raw);
  const out = [];
  for (let t = Math.floor(lo / step) * step; t <= hi + step * 1e-9; t += step) out.push(Number(t.toPrecision(12)));
  if (out[out.length - 1] < hi) out.push(Number((out[out.length - 1] + step).toPrecision(12)));
  return out;
}

function yName(y) { return y === "mks" ? "Mks" : "control peak |u|"; }

function showCurve(d) {
  state.curve = d;
  const sec = $("#tradeoff");
  sec.hidden = false;
  const n = d.points.length;
  $("#tradeoff-title").textContent = `${d.structure}: ${n} verified point${n === 1 ? "" : "s"}, settling time vs ${yName(d.y)}` +
    `, ${fmt(d.wall_time_s)} s`;
  const skipped = $("#tradeoff-skipped");
  skipped.replaceChildren();
  for (const s of d.skipped || []) {
    const li = document.createElement("li");
    li.textContent = `left out: ${yName(d.y)} ≤ ${fmt(s.limit)}: ${s.why}`;
    skipped.append(li);
  }
  drawCurve(d);
  const pick = $("#tradeoff-pick");
  pick.max = String(Math.max(0, n - 1));
  pick.value = "0";
  pick.disabled = n < 2;
  $("#tradeoff-use").disabled = n === 0;
  if (n) pickPoint(0);
  else $("#tradeoff-point").textContent = "no point met the spec";
}

function drawCurve(d) {
  const W = 640, H = 300, L = 64, R = 16, T = 14, B = 46;
  const pts = d.points.map((p) => [Number(p.settling_time_s), Number(p[d.y])]);
  const root = $("#curve");
  root.replaceChildren();
  root.setAttribute("viewBox", `0 0 ${W} ${H}`);
  root.setAttribute("aria-label", `trade-off curve: settling time against ${yName(d.y)}`);
  const xt = ticks(Math.min(...pts.map((p) => p[0])), Math.max(...pts.map((p) => p[0])));
  const yt = ticks(Math.min(...pts.map((p) => p[1])), Math.max(...pts.map((p) => p[1])));
  const [x0, x1, y0, y1] = [xt[0], xt[xt.length - 1], yt[0], yt[yt.length - 1]];
  const X = (v) => L + (v - x0) / (x1 - x0) * (W - L - R);
  const Y = (v) => H - B - (v - y0) / (y1 - y0) * (H - T - B);
  const grid = svg("g", { class: "grid" }, root);
  for (const t of xt) {
    svg("line", { x1: X(t), x2: X(t), y1: T, y2: H - B }, grid);
    svg("text", { x: X(t), y: H - B + 16, class: "tick", "text-anchor": "middle" }, root, fmt(t));
  }
  for (const t of yt) {
    svg("line", { x1: L, x2: W - R, y1: Y(t), y2: Y(t) }, grid);
    svg("text", { x: L - 6, y: Y(t) + 4, class: "tick", "text-anchor": "end" }, root, fmt(t));
  }
  svg("rect", { x: L, y: T, width: W - L - R, height: H - T - B, class: "frame" }, root);
  svg("text", { x: L + (W - L - R) / 2, y: H - 8, class: "axis", "text-anchor": "middle" }, root, "settling time [s]");
  svg("text", { x: 14, y: T + (H - T - B) / 2, class: "axis", "text-anchor": "middle",
                transform: `rotate(-90 14 ${T + (H - T - B) / 2})` }, root, yName(d.y));
  svg("polyline", { points: pts.map(([x, y]) => `${X(x)},${Y(y)}`).join(" "), class: "line" }, root);
  pts.forEach(([x, y], i) => {
    const c = svg("circle", { cx: X(x), cy: Y(y), r: 6, class: "pt", "data-i": i }, root);
    svg("title", {}, c, `point ${i + 1}: settling ${fmt(x)} s, ${yName(d.y)} ${fmt(y)}`);
    svg("text", { x: X(x) + 9, y: Y(y) - 8, class: "num" }, root, String(i + 1));
    c.addEventListener("click", () => { $("#tradeoff-pick").value = String(i); pickPoint(i); });
  });
}

function pickPoint(i) {
  const d = state.curve;
  const p = d.points[i];
  for (const c of $$("#tradeoff-plot circle.pt")) c.classList.toggle("on", Number(c.dataset.i) === i);
  $("#tradeoff-point").textContent = `point ${i + 1} of ${d.points.length}: settling ${fmt(p.settling_time_s)} s, ` +
    `${yName(d.y)} ${fmt(p[d.y])}` + (p.limit === null || p.limit === undefined ? "" : ` (tuned with ${yName(d.y)} ≤ ${fmt(p.limit)})`);
  showResult(p.result, { title: `Trade-off point ${i + 1} of ${d.points.length}` });
}

// The point's limit into the form: the problem that point solves, to tune (and store) it.
function useLimit() {
  const d = state.curve;
  const p = d?.points[Number($("#tradeoff-pick").value)];
  if (!p || p.limit === null || p.limit === undefined) return;
  const k = d.y === "mks" ? "mks_max" : "control_peak_max";
  field(k).value = String(p.limit);  // exactly: a rounded limit could be tighter than the point's
  syncURL();
  $("#progress").textContent = `${k} = ${field(k).value} is in the form: tune to store this design`;
}

// -- showing a result ----------------------------------------------------------------------------

function cell(tr, text, cls) { const td = tr.insertCell(); td.textContent = text; if (cls) td.className = cls; return td; }

function table(el, rows) {
  el.replaceChildren();
  for (const [k, v] of rows) { const tr = el.insertRow(); cell(tr, k); cell(tr, v, "num"); }
}

function polynomial(c) { return `[${c.map((x) => fmt(x)).join(", ")}]`; }

// d: a tune result (stored: it has an id; a trade-off point's result has none: no plots, no export).
function showResult(d, { title = "Result" } = {}) {
  state.result = d;
  $("#export-force").checked = false;  // a file for a design that fails its verdict is asked for each time
  const stored = Boolean(d.id);
  state.id = stored ? d.id : null;
  $("#result").hidden = false;
  $("#result-title").textContent = title;
  $("#result-link").hidden = !stored;
  if (stored) $("#result-link").href = `/?id=${encodeURIComponent(d.id)}`;
  $("#stored-only").hidden = !stored;
  $("#unstored").hidden = stored;
  if (stored) for (const c of $$("#curve circle.pt.on")) c.classList.remove("on");  // not a point of the curve
  const v = $("#verdict");
  const several = (d.plants || []).length > 1;
  v.textContent = d.verdict ? (several && d.meets_spec ? d.verdict.replace("meets the spec", `meets the spec on all ${d.plants.length} plants`) : d.verdict)
    : d.meets_spec ? (several ? `meets spec on all ${d.plants.length} plants` : "meets spec")
    : `does NOT meet spec: failing ${d.failing.map(label).join(", ")}`;
  v.className = d.meets_spec ? "ok" : "bad";
  showAirframe(d);
  const bounds = $("#at-bounds");  // the parameters on a search bound or a default limit, and the rule that decides
  bounds.replaceChildren();
  for (const b of d.at_bounds || []) {
    const li = document.createElement("li");
    li.textContent = b.text;
    bounds.append(li);
  }
  const lim = $("#limits");
  lim.replaceChildren();
  for (const x of d.limits || []) {
    const li = document.createElement("li");
    const code = document.createElement("code");
    code.textContent = x.field;
    li.append(code, ` = ${fmt(x.value)}: ${x.rule}`);
    lim.append(li);
  }
  $("#limits-used").hidden = !(d.limits || []).length;
  const why = $("#reasons");  // why an unmet spec is not met, and a spec change the search found feasible
  why.replaceChildren();
  for (const r of d.reasons || []) {
    const li = document.createElement("li");
    const hint = Object.entries(r.suggest || {}).map(([k, x]) => `${k} = ${x === null ? "none" : fmt(x)}`).join(", ");
    li.textContent = r.message + (hint ? ` (try ${hint})` : "");
    why.append(li);
  }
  table($("#gains"), Object.entries(d.gains).map(([k, x]) => [k, fmt(x)]));
  const c = d.controller;
  $("#controller-tf").textContent = `C(${c.dt ? "z" : "s"}) = ${polynomial(c.num)} / ${polynomial(c.den)}` + (c.dt ? `, dt = ${c.dt} s` : "");
  const body = $("#checks tbody");
  body.replaceChildren();
  for (const ch of d.checks) {
    const tr = body.insertRow();
    cell(tr, label(ch.name));
    cell(tr, `${OPS[ch.op] || ch.op} ${fmt(ch.required)}${ch.name === "crossover_rad_s" ? " ± 1 %" : ""}`, "num");
    const unmeasured = ch.name.startsWith("measured_") && (ch.achieved === "NaN" || Number.isNaN(ch.achieved));
    cell(tr, unmeasured ? "not measured" : fmt(ch.achieved), "num");
    cell(tr, ch.ok ? "✓ met" : "✗ not met", ch.ok ? "met" : "unmet");
  }
  const members = $("#members");
  members.replaceChildren();
  if (several) {
    const t = document.createElement("table");
    d.plants.forEach((p, i) => {
      const tr = t.insertRow();
      cell(tr, i === 0 ? "nominal" : `plant ${i + 1}`);
      const bad = p.checks.filter((x) => !x.ok).map((x) => label(x.name));
      cell(tr, p.meets_spec ? "✓ meets spec" : `✗ ${bad.join(", ")}`, p.meets_spec ? "met" : "unmet");
    });
    members.append(t);
  }
  table($("#metrics"), Object.entries(d.metrics).map(([k, x]) => [label(k), fmt(x)]));
  $("#current-block").hidden = !d.current;
  if (d.current) {  // the vehicle's current tune next to the proposed one
    const rows = [["gains", Object.entries(d.current.gains).filter(([k]) => ["P", "I", "D", "FF"].includes(k)).map(([k, x]) => `${k} ${fmt(x)}`).join(", ")],
                  ["verdict", d.current.verdict || (d.current.meets_spec ? "meets spec" : "does NOT meet spec")]];
    for (const k of ["phase_margin_deg", "gain_margin_db", "ms", "overshoot_pct", "settling_time_s"]) rows.push([label(k), `${fmt(d.current.metrics[k])} (proposed ${fmt(d.metrics[k])})`]);
    table($("#current"), rows);
  }
  for (const f of CONFIG.firmwares) {
    const b = $(`#export .tabs button[data-format=${f.format}]`);
    b.hidden = d.structure !== f.structure;
  }
  if (!FIRMWARE.has(d.structure) && PARAM_FORMATS.has(state.exportFormat)) state.exportFormat = "c";
  const s = d.solver || {};
  $("#solver").textContent = `${s.method || "solver"}: ${fmt(s.wall_time_s)} s, seed ${fmt(s.seed)}` +
    (s.budget_exhausted ? "; the time budget ran out (best verified design)" : "") +
    (s.optimality?.summary ? `. ${s.optimality.summary}` : "") +
    ((s.notes || []).length ? `. Note: ${s.notes.join(" Note: ")}` : "");
  $("#export-ct").hidden = Boolean(c.dt);
  if (!stored) return;
  showPlots(d.id);
  loadExport();
}

// What the verdict rests on, next to it: the identification's rating, the loop on its measured response (the margins
// with the range their error spans; the checks judge the worst end), and a proposal far from the vehicle's current tune.
function showAirframe(d) {
  const box = $("#airframe");
  box.replaceChildren();
  const line = (text, cls) => { const p = document.createElement("p"); p.textContent = text; if (cls) p.className = cls; box.append(p); return p; };
  const id = d.identification;
  if (id) {
    const ok = id.quality === "good" || id.quality === "acceptable";
    const p = line(`identification: rated ${id.quality} (J ${fmt(id.cost)}, time-domain check ${id.check || "none"})` +
                   (ok ? "" : ": below acceptable, so every figure here is the model's only"), ok ? "hint" : "bad");
    p.id = "airframe-identification";
  }
  const m = d.measured;
  if (m) {
    const fig = (name, v, r, unit) => (v === "NaN" || Number.isNaN(v) ? `${name} not measured` : `${name} ${fmt(v)}${unit} (${fmt(r[0])}…${fmt(r[1])})`);
    const f = m.measured;
    const p = line(`on the measured response (${fmt(m.band_rad_s[0])}–${fmt(m.band_rad_s[1])} rad/s, ${m.points} coherent points): ` +
                   [fig("PM", f.phase_margin_deg, f.phase_margin_range, "°"), fig("GM", f.gain_margin_db, f.gain_margin_range, " dB"),
                    fig("Ms", f.ms, f.ms_range, "")].join(", "));
    p.id = "airframe-measured";
    for (const w of m.warnings || []) line(`warning: ${w}`, "bad");
  }
  for (const w of d.vehicle?.warnings || []) line(`the vehicle's parameters: ${w}`, "bad");
  const changes = d.vehicle?.changes || [];
  if (changes.length) {
    const p = line(`the proposal changes the vehicle's current tune by more than 3×: ${changes.join("; ")}`, "bad");
    p.id = "airframe-changes";
  }
  box.hidden = !box.childElementCount;
}

async function showPlots(id) {
  for (const u of state.urls) URL.revokeObjectURL(u);
  state.urls = [];
  await Promise.all($$("#plots figure").map(async (fig) => {
    const img = $("img", fig);
    img.removeAttribute("src");
    fig.classList.remove("ready");
    const r = await api(`/tunes/${encodeURIComponent(id)}/plot.svg?kind=${fig.dataset.kind}`);
    if (!r.ok) { img.alt = `plot unavailable (${r.status})`; return; }
    const url = URL.createObjectURL(await r.blob());
    state.urls.push(url);
    img.src = url;
    $("a", fig).href = url;
    await img.decode().catch(() => {});
    fig.classList.add("ready");
  }));
}

const SUFFIX = { c: "c", python: "py", text: "txt" };

async function loadExport() {
  if (!state.id) return;
  const f = state.exportFormat;
  const root = $("#export");
  for (const b of $$("#export .tabs button[data-format]")) b.classList.toggle("on", b.dataset.format === f);
  $("#export-force-field").hidden = !PARAM_FORMATS.has(f);
  if (PARAM_FORMATS.has(f)) { await loadParamFile(f); return; }
  $("#export-warnings").hidden = true;
  clearErrors(root);
  for (const b of $$(".tabs button[data-format]", root)) b.classList.toggle("on", b.dataset.format === f);
  const name = $("#export-name").value.trim() || "controller";
  const q = new URLSearchParams({ format: f, name });
  const continuous = !$("#export-ct").hidden;
  if (continuous) {
    if ($("#export-dt").value) q.set("dt", $("#export-dt").value);
    q.set("method", $("#export-method").value);
  }
  if ($("#export-umin").value) q.set("u_min", $("#export-umin").value);
  if ($("#export-umax").value) q.set("u_max", $("#export-umax").value);
  const pre = $("#export-code");
  pre.textContent = continuous && !q.has("dt") ? "a continuous controller: give the sample time dt to export it" : "…";
  noDownload();
  if (continuous && !q.has("dt")) return;
  const r = await api(`/tunes/${encodeURIComponent(state.id)}/export?${q}`);
  if (r.ok) {
    offer(await r.text(), `${name}.${SUFFIX[f]}`);
    return;
  }
  const d = await answer(r);
  pre.textContent = "";
  if (r.status === 422 && Array.isArray(d.detail)) showErrors(root, d.detail, $("#export-error"));
  else showGeneral($("#export-error"), errorText(r, d));
}

// no file to download (before an export's answer, and after a failed one): the link is hidden, its file released
function noDownload() {
  const link = $("#export-download");
  link.removeAttribute("href");
  link.textContent = "download";
  link.hidden = true;
  if (state.exportUrl) URL.revokeObjectURL(state.exportUrl);
  state.exportUrl = null;
}

// the exported text shown, and offered as a file to download
function offer(text, filename) {
  $("#export-code").textContent = text;
  if (state.exportUrl) URL.revokeObjectURL(state.exportUrl);
  state.exportUrl = URL.createObjectURL(new Blob([text], { type: "text/plain" }));
  const link = $("#export-download");
  link.href = state.exportUrl;
  link.download = filename;
  link.hidden = false;
}

// a firmware law's parameter file (the ground station's format), for download
async function loadParamFile(f) {
  clearErrors($("#export"));
  $("#export-error").hidden = true;
  const warn = $("#export-warnings");
  warn.replaceChildren();
  warn.hidden = true;
  // the result's own axis when it was tuned for a vehicle (another one is refused), else the form's
  const q = new URLSearchParams({ format: f, axis: state.result?.vehicle?.axis || $("#vehicle-axis").value });
  if ($("#export-force").checked) q.set("force", "true");
  const pre = $("#export-code");
  const link = $("#export-download");
  pre.textContent = "…";
  noDownload();
  const r = await api(`/tunes/${encodeURIComponent(state.id)}/export?${q}`);
  if (r.ok) {
    const name = (r.headers.get("content-disposition") || "").match(/filename="([^"]+)"/)?.[1] || `${f}.txt`;
    offer(await r.text(), name);
    link.textContent = `download ${name}`;
    for (const w of (r.headers.get("x-tuner-warning") || "").split("; ").filter(Boolean)) {
      const li = document.createElement("li");
      li.textContent = `warning: ${w}`;
      warn.append(li);
    }
    warn.hidden = !warn.childElementCount;
    return;
  }
  const d = await answer(r);
  pre.textContent = "";
  showGeneral($("#export-error"), errorText(r, d));
}

async function loadStored(id) {
  const r = await api(`/tunes/${encodeURIComponent(id)}`);
  const d = await answer(r);
  if (!r.ok) { showGeneral($("#form-error"), `stored result ${id}: ${errorText(r, d)}`); return; }
  const q = d.request || {};
  const v = fromRequest(q);
  if (q.identification_id && (d.plants || []).length) {  // its plant was the identification's fitted model
    const p = d.plants[0];
    Object.assign(v, { plant: "", num: p.num.map((x) => String(Number(x.toPrecision(8)))).join(", "),
                       den: p.den.map((x) => String(Number(x.toPrecision(8)))).join(", "), var: "s",
                       delay: p.delay ? String(Number(p.delay.toPrecision(6))) : "", plants: [] });
  }
  writeForm(v);
  state.ident = null;
  if (q.identification_id) rememberIdent(q.identification_id);
  showResult(d);
  syncURL({ id: d.id });
}

function fromRequest(q) {
  const v = {};
  const p = q.plant || {};
  if (p.expr) v.plant = p.expr;
  else if (p.num) { v.num = p.num.join(", "); v.den = p.den.join(", "); v.var = p.dt ? "z" : "s"; }
  if (p.delay) v.delay = String(p.delay);
  if (q.dt) v.dt = String(q.dt);
  v.structure = (CONFIG.deprecated_structures || {})[q.structure] || q.structure; // pidf2 -> pid_mf2
  for (const [k, x] of Object.entries(q.spec || {})) v[k] = specValue(k, x);
  if (q.options) {
    v.seed = String(q.options.seed ?? 0);
    if (q.options.time_budget_s) v.budget = String(q.options.time_budget_s);
    v.effort = q.options.effort || "default";
  }
  v.plants = (q.plants || []).filter((x) => x.expr).map((x) => x.expr);
  return v;
}

// -- history -------------------------------------------------------------------------------------

async function loadHistory(offset) {
  const body = $("#history-table tbody");
  const r = await api(`/tunes?limit=${HIST}&offset=${offset}`);
  const d = await answer(r);
  if (!r.ok) { body.replaceChildren(); const tr = body.insertRow(); cell(tr, errorText(r, d)); return; }
  state.histOffset = d.offset;
  body.replaceChildren();
  for (const it of d.items) {
    const tr = body.insertRow();
    cell(tr, new Date(it.created_at).toLocaleString());
    cell(tr, it.structure);
    cell(tr, it.meets_spec ? "✓ meets spec" : "✗ not met", it.meets_spec ? "met" : "unmet");
    const a = document.createElement("a");
    a.href = `/?id=${encodeURIComponent(it.id)}`;
    a.textContent = it.id.slice(0, 10);
    a.title = it.id;
    tr.insertCell().append(a);
  }
  const last = d.offset + d.items.length;
  $("#hist-range").textContent = d.total ? `${d.offset + 1}–${last} of ${d.total}` : "none yet";
  $("#hist-prev").disabled = d.offset === 0;
  $("#hist-next").disabled = last >= d.total;
}

// -- identification from a CSV log ---------------------------------------------------------------

const csv = { names: [], rows: [], ulog: null, params: "", loopHz: null };

function parseCSV(text) {
  const lines = text.split(/\r?\n/).filter((l) => l.trim() && !l.startsWith("#"));
  const sep = [",", ";", "\t"].find((s) => lines[0].includes(s)) || /\s+/;
  const split = (l) => l.split(sep).map((x) => x.trim());
  const first = split(lines[0]);
  const header = first.some((x) => x !== "" && !Number.isFinite(Number(x)));
  const names = header ? first : first.map((_, i) => `column ${i + 1}`);
  return { names, rows: (header ? lines.slice(1) : lines).map(split) };
}

function options(sel, names, pick, none) {
  sel.replaceChildren();
  if (none) sel.append(new Option(none, ""));
  names.forEach((n, i) => sel.append(new Option(n, String(i))));
  sel.value = pick < 0 ? "" : String(pick);
}

function base64(buf) {
  const bytes = new Uint8Array(buf);
  let bin = "";
  for (let i = 0; i < bytes.length; i += 0x8000) bin += String.fromCharCode(...bytes.subarray(i, i + 0x8000));
  return btoa(bin);
}

// a flight log (a PX4 ULog or an ArduPilot DataFlash .bin): its signals and stored parameters, read by the service
// (POST /ulog/signals). Only rate signals are preselected (the command in, the measured rate out, the rate setpoint as
// the reference), else nothing: a command is never offered as the output. dt is the vehicle's rate loop, from the
// parameter the log names, and the page says which; the identification's grid is the log's own (no rate_hz sent)
const RATE_INPUTS = /^(vehicle_torque_setpoint\.xyz\[0\]|actuator_controls_0\.control\[0\]|RATE\.ROut)$/;
const RATE_OUTPUTS = /^(vehicle_angular_velocity\.xyz\[0\]|vehicle_attitude\.rollspeed|RATE\.R)$/;
const RATE_REFERENCES = /^(vehicle_rates_setpoint\.roll|RATE\.RDes)$/;

async function loadULog(file) {
  const data = base64(await file.arrayBuffer());
  $("#csv-info").innerHTML = '<span class="spinner"></span> reading the log…';
  const r = await api("/ulog/signals", { method: "POST", json: { data } });
  const d = await answer(r);
  if (!r.ok) { $("#csv-info").textContent = ""; showGeneral($("#ident-out"), errorText(r, d)); return; }
  const names = d.signals.map((x) => x.name);
  Object.assign(csv, { names, rows: [], ulog: data, params: d.params_text || "", loopHz: d.loop_hz || null });
  const find = (re) => names.findIndex((n) => re.test(n));
  options($("#col-input"), names, find(RATE_INPUTS), "choose the plant input (a command)");
  options($("#col-output"), names, find(RATE_OUTPUTS), "choose the plant output (a measured rate)");
  options($("#col-reference"), names, find(RATE_REFERENCES), "none (open loop)");
  $("#col-time-field").hidden = true;
  $("#csv-columns").hidden = false;
  const src = $("#dt-source");
  if (csv.loopHz) {  // the sample time of the vehicle's rate loop, as the log's parameters name it
    field("dt").value = String(Number((1 / csv.loopHz).toPrecision(6)));
    src.textContent = `dt from the vehicle: ${d.loop_from || "its loop rate"} = ${csv.loopHz} Hz in ${file.name}`;
    syncURL();
  } else {
    src.textContent = `${file.name} does not name the rate loop's rate (${CONFIG.firmwares.find((f) => f.name === d.firmware)?.loop_param || "its loop rate parameter"}): `
      + "dt is left empty (a firmware law takes the vehicle's rate, the result says from where), not the log's grid; give the loop's sample time if you know it";
  }
  $("#vehicle-from-log").disabled = !csv.params;
  $("#vehicle-from-log").checked = Boolean(csv.params);
  $("#csv-info").textContent = `${names.length} signals` + (d.firmware ? `; ${d.firmware} parameters stored` : "");
}

async function loadCSV(file) {
  clearErrors($("#ident"));
  $("#ident-out").hidden = true;
  const head = new Uint8Array(await file.slice(0, 7).arrayBuffer());
  const lower = file.name.toLowerCase();
  const dataflash = head[0] === 0xa3 && head[1] === 0x95 && head[2] === 0x80;  // a DataFlash log's first FMT
  if (lower.endsWith(".ulg") || lower.endsWith(".bin") || dataflash || String.fromCharCode(...head) === "ULog\x01\x125") {
    await loadULog(file);
    return;
  }
  const parsed = parseCSV(await file.text());
  Object.assign(csv, parsed, { ulog: null, params: "", loopHz: null });
  $("#dt-source").textContent = "";
  $("#col-time-field").hidden = false;
  const find = (re) => parsed.names.findIndex((n) => re.test(n));
  const t = find(/^(t|time)\b/i);
  const rest = parsed.names.map((_, i) => i).filter((i) => i !== t);
  const inp = find(/(cmd|input|^u$)/i) >= 0 ? find(/(cmd|input|^u$)/i) : rest[0] ?? 0;
  const out = rest.find((i) => i !== inp) ?? 0;
  options($("#col-time"), parsed.names, t, "none (rate = 1/dt)");
  options($("#col-input"), parsed.names, inp);
  options($("#col-output"), parsed.names, out);
  options($("#col-reference"), parsed.names, find(/(setpoint|reference|^r$|_sp$)/i), "none (open loop)");
  $("#csv-columns").hidden = false;
  $("#csv-info").textContent = `${parsed.rows.length} rows, ${parsed.names.length} columns`;
}

function column(sel, errs) {
  const i = Number(sel.value);
  const out = [];
  csv.rows.forEach((r, k) => {
    const v = Number(r[i]);
    if (!Number.isFinite(v) && errs.length < 3) errs.push({ loc: ["body", "input"], msg: `row ${k + 1}, ${csv.names[i]}: not a number: ${r[i]}` });
    out.push(v);
  });
  return out;
}

async function identify() {
  const root = $("#ident");
  clearErrors(root);
  $("#ident-result").hidden = true;
  const errs = [];
  const body = { poles: number($("#id-poles").value, ["body", "poles"], errs, { int: true }) ?? 2,
                 zeros: number($("#id-zeros").value, ["body", "zeros"], errs, { int: true }) ?? 0 };
  const dt = Number(field("dt").value) || null;
  body.delay = $("#id-delay").checked ? "auto" : null;  // the delay as fitted: the loop takes any delay exactly
  const ref = $("#col-reference").value;
  if (csv.ulog) {  // the log's own grid (its slower signal's rate): dt is the loop's, not the identification's
    for (const [sel, role] of [[$("#col-input"), "input"], [$("#col-output"), "output"]]) {
      if (sel.value === "") errs.push({ loc: ["body", "ulog", role], msg: `choose the plant ${role} among the log's signals` });
    }
    body.ulog = { data: csv.ulog, input: csv.names[Number($("#col-input").value)],
                  output: csv.names[Number($("#col-output").value)] };
    if (ref !== "") body.ulog.reference = csv.names[Number(ref)];
  } else {
    body.input = column($("#col-input"), errs);
    body.output = column($("#col-output"), errs);
    if (ref !== "") body.reference = column($("#col-reference"), errs);
    if ($("#col-time").value !== "") body.time = column($("#col-time"), errs);
    else if (dt) body.rate_hz = 1 / dt;
    else errs.push({ loc: ["body", "rate_hz"], msg: "choose the time column, or give dt (the log's sample time)" });
  }
  if (errs.length) { showErrors(root, errs, $("#ident-out")); return; }
  const btn = $("#identify-btn");
  btn.disabled = true;
  $("#csv-info").innerHTML = '<span class="spinner"></span> identifying…';
  try {
    const r = await api("/identify", { method: "POST", json: body });
    const d = await answer(r);
    $("#csv-info").textContent = "";
    if (r.status === 422 && Array.isArray(d.detail)) { showErrors(root, d.detail, $("#ident-out")); return; }
    if (!r.ok) { showGeneral($("#ident-out"), errorText(r, d)); return; }
    const m = d.model;
    writeForm({ ...readForm(), plant: "", num: m.num.map((x) => String(Number(x.toPrecision(8)))).join(", "),
                den: m.den.map((x) => String(Number(x.toPrecision(8)))).join(", "), var: "s",
                delay: m.delay ? String(Number(m.delay.toPrecision(6))) : "", plants: readForm().plants });
    rememberIdent(d.id);  // the tune is sent with it: judged on the measured response too
    const res = $("#ident-result");
    res.hidden = false;
    res.replaceChildren();
    res.className = "ident-pair";  // the verdict beside its plot
    const side = document.createElement("div");
    side.className = "ident-verdict";
    const q = document.createElement("p");
    q.className = d.quality === "good" || d.quality === "acceptable" ? "ok" : "bad";
    q.id = "ident-quality";
    q.textContent = `verdict: ${d.quality}` + (d.options?.estimate ? ` (${d.options.estimate} estimate)` : "");
    side.append(q);
    if (d.closed_loop?.detected) {
      const cl = document.createElement("p");
      cl.id = "ident-closed-loop";
      cl.className = d.quality === "closed-loop" ? "bad" : "hint";
      cl.textContent = d.closed_loop.message;
      side.append(cl);
    }
    const p = document.createElement("p");
    const others = d.warnings.filter((w) => w !== d.closed_loop?.message);
    p.textContent = `J's verdict and the time-domain check (${d.check || "none"}): ${d.verdict}` + (others.length ? ` — ${others.join("; ")}` : "") +
      ". The plant below is the fitted model; a tune is sent with this identification, and judged on its measured response too.";
    side.append(p);
    const pr = await api(`/identifications/${encodeURIComponent(d.id)}/plot.svg`);
    if (pr.ok) { const img = document.createElement("img"); img.alt = "identification fit"; img.src = URL.createObjectURL(await pr.blob()); img.className = "fit"; res.append(img); }
    res.append(side);
    syncURL();
  } finally {
    btn.disabled = false;
  }
}

// -- wiring --------------------------------------------------------------------------------------

function init() {
  const sel = field("structure");
  for (const s of CONFIG.structures) sel.append(new Option(`${s.name} (${s.params.join(", ")})`, s.name));
  const obj = field("objective");
  const maximised = { bandwidth: "maximise bandwidth", disk_margin: "maximise disk margin", ie: "minimise |IE| (maximise Ki)",
                      mks: "minimise Mks (noise sensitivity)" };
  maximised.auto = "auto: the structure decides (settling time; a 2-DOF law: the load too)";
  for (const o of CONFIG.objectives) obj.append(new Option(maximised[o] || `minimise ${o.replaceAll("_", " ")}`, o));
  for (const k of SPEC) {  // the library's description as the tooltip, unless the page has its own (the limits)
    const el = field(k)?.closest(".field");
    if (el && CONFIG.spec_help[k] && !el.title) el.title = CONFIG.spec_help[k];
  }
  const ys = field("y");
  ys.replaceChildren(...CONFIG.tradeoff.y.map((y) => new Option(y === "mks" ? "Mks (noise sensitivity)" : "control peak |u|", y)));
  field("points").max = CONFIG.tradeoff.max_points;
  const range = $("input[type=range][data-sync=budget]");
  range.max = CONFIG.max_budget_s;
  field("budget").max = CONFIG.max_budget_s;

  const params = new URLSearchParams(location.search);
  const given = fromParams(params);
  const empty = !NAMES.some((n) => params.has(n)) && !params.has("id");
  writeForm(empty ? { ...ROLL } : given);
  if (params.get("identification")) rememberIdent(params.get("identification"));

  form.addEventListener("input", (e) => {
    const t = e.target;
    if (t.dataset.sync) { field(t.dataset.sync).value = t.value; }
    else syncSliders();
    if (t.name === "structure") structureHint();
    if (t.id === "thesis") setThesis(t.checked);
    if (t.id === "thesis" || LIMITS.includes(t.name)) syncThesis();
    if (t.name !== "pmode" && t.type !== "file") syncURL();
  });
  for (const r of $$("input[name=pmode]")) r.addEventListener("change", () => { setMode(mode()); syncURL(); });
  form.addEventListener("submit", (e) => { e.preventDefault(); runTune(); });
  $("#cancel-btn").addEventListener("click", () => state.running?.abort());
  $("#tradeoff-btn").addEventListener("click", runTradeoff);
  $("#tradeoff-pick").addEventListener("input", (e) => pickPoint(Number(e.target.value)));
  $("#tradeoff-use").addEventListener("click", useLimit);
  $("#share-btn").addEventListener("click", async () => {
    const url = `${location.origin}/?${formParams({ run: "1" })}`;
    try { await navigator.clipboard.writeText(url); $("#progress").textContent = "link copied (it runs the tune when opened)"; }
    catch { $("#progress").textContent = url; }
  });
  $("#csv-file").addEventListener("change", (e) => { if (e.target.files[0]) loadCSV(e.target.files[0]); });
  $("#vehicle-file").addEventListener("change", async (e) => {
    const f = e.target.files[0];
    state.vehicleText = f ? await f.text() : null;
    $("#vehicle-info").textContent = f ? `${f.name}: the loop rate, filters and current gains come from it` : "";
    if (f) $("#vehicle-from-log").checked = false;
  });
  field("structure").addEventListener("change", vehicleRow);
  vehicleRow();
  $("#identify-btn").addEventListener("click", identify);
  for (const b of $$("#export .tabs button[data-format]")) b.addEventListener("click", () => { state.exportFormat = b.dataset.format; loadExport(); });
  for (const id of ["#export-name", "#export-dt", "#export-method", "#export-umin", "#export-umax", "#export-force"]) $(id).addEventListener("change", loadExport);
  $("#export-copy").addEventListener("click", () => navigator.clipboard?.writeText($("#export-code").textContent));
  $("#hist-prev").addEventListener("click", () => loadHistory(Math.max(0, state.histOffset - HIST)));
  $("#hist-next").addEventListener("click", () => loadHistory(state.histOffset + HIST));
  $("#key-form").addEventListener("submit", (e) => {
    e.preventDefault();
    const v = $("#api-key").value.trim();
    if (v) sessionStorage.setItem(KEY, v); else sessionStorage.removeItem(KEY);
    keyState(v ? "key set for this tab" : "no key");
    loadHistory(state.histOffset);
  });
  if (sessionStorage.getItem(KEY)) keyState("key set for this tab");
  else if (CONFIG.api_key_required) keyState("this service needs an API key", true);

  loadHistory(0);
  if (params.get("run") === "1") runTune();
  else if (params.get("run") === "tradeoff") runTradeoff();
  else if (params.get("id")) loadStored(params.get("id"));
}

init();
