// farfield dashboard: plain JavaScript, no build step, no external resources.
// Every API call carries the key from localStorage as "Authorization: Bearer <key>".
"use strict";

const KEY_STORAGE = "farfield.apiKey";
const POLL_MS = 1000;
const FINAL = new Set(["done", "failed", "cancelled"]);
const SVG_NS = "http://www.w3.org/2000/svg";

const $ = (id) => document.getElementById(id);

const state = {
  key: localStorage.getItem(KEY_STORAGE) || "",
  view: "home",
  jobId: null,
  job: null,
  jobFetchedAt: 0,
  scenes: new Map(), // id -> scene record (a summary: its objects are GET objects_url, paged)
  sceneObjects: new Map(), // id -> the names of its first objects, for the job form
  map: null, // {key, rects: Map(index -> {rect, title, bar, w})}
  level: 0, // y level shown on the map (grid jobs)
  selected: null, // selected cell index
  atlas: {key: null, url: null}, // what the thumbnail shows
  polling: false,
  techniques: new Map(), // name -> GET /v1/techniques entry
  optionFields: new Map(), // technique name -> its option fields (kept across switches)
  placement: {key: null, doc: null, error: null}, // a placement job's GET /v1/jobs/{id}/placement, fetched once per end
  region: null, // the footprint key of the region selected on the placement map
  colour: "after", // the placement map's colour: estimated time "before" or "after" placement
};

const PLACEMENT = "placement"; // the job type of a placement job

// ---------------------------------------------------------------- API

class ApiError extends Error {
  constructor(status, message, kind) {
    super(message);
    this.status = status;
    this.kind = kind;
  }
}

function errorMessage(status, body) {
  // {"detail": "...", "error": "Type"} or FastAPI's 422 {"detail": [{loc, msg}, ...]}
  if (body && Array.isArray(body.detail)) {
    return body.detail.map((d) => {
      const loc = (d.loc || []).filter((p) => p !== "body").join(".");
      return (loc ? loc + ": " : "") + (d.msg || JSON.stringify(d));
    }).join("\n");
  }
  if (body && typeof body.detail === "string") return body.detail;
  return `HTTP ${status}`;
}

async function api(path, {method = "GET", json, form, raw = false} = {}) {
  const headers = {};
  const key = state.key;
  if (key) headers["Authorization"] = "Bearer " + key;
  let body;
  if (json !== undefined) {
    headers["Content-Type"] = "application/json";
    body = JSON.stringify(json);
  } else if (form !== undefined) {
    body = form;
  }
  let response;
  try {
    response = await fetch(path, {method, headers, body});
  } catch (error) {
    throw new ApiError(0, `cannot reach the service: ${error.message}`, "NetworkError");
  }
  if (!response.ok) {
    let parsed = null;
    try { parsed = await response.json(); } catch (_) { /* not JSON */ }
    const error = new ApiError(response.status, errorMessage(response.status, parsed), parsed && parsed.error);
    // (An answer to a key changed meanwhile says nothing about the key in use now.)
    if (response.status === 401 && key === state.key) showGlobalError(`API key rejected: ${error.message}`);
    throw error;
  }
  if (raw) return response;
  if (response.status === 204) return null;
  return response.json();
}

// A page of a paged listing (GET /v1/scenes, /v1/jobs, a scene's objects): the body is a JSON
// array of the page, X-Total-Count the entries in all pages.
async function apiPage(path) {
  const response = await api(path, {raw: true});
  const items = await response.json();
  const total = Number(response.headers.get("X-Total-Count") ?? items.length);
  return {items, total};
}

function showMore(node, shown, total, what) {
  node.hidden = total <= shown;
  node.textContent = `the newest ${fmtNum(shown)} of ${fmtNum(total)} ${what} are listed`;
}

async function download(path, filename) {
  try {
    const response = await api(path, {raw: true});
    const url = URL.createObjectURL(await response.blob());
    const a = document.createElement("a");
    a.href = url;
    a.download = filename;
    document.body.appendChild(a);
    a.click();
    a.remove();
    setTimeout(() => URL.revokeObjectURL(url), 10000);
  } catch (error) {
    showBox($("job-action-error"), `download failed: ${error.message}`);
  }
}

// ---------------------------------------------------------------- small helpers

function el(tag, attrs = {}, ...children) {
  const node = document.createElement(tag);
  for (const [name, value] of Object.entries(attrs)) {
    if (value === undefined || value === null || value === false) continue;
    if (name === "class") node.className = value;
    else if (name === "text") node.textContent = value;
    else node.setAttribute(name, value === true ? "" : value);
  }
  for (const child of children) if (child !== null && child !== undefined) node.append(child);
  return node;
}

function svg(tag, attrs = {}) {
  const node = document.createElementNS(SVG_NS, tag);
  for (const [name, value] of Object.entries(attrs)) node.setAttribute(name, value);
  return node;
}

function showBox(node, message) {
  node.textContent = message || "";
  node.hidden = !message;
}

function showGlobalError(message) { showBox($("global-error"), message); }

function fmtNum(x, digits = 3) {
  if (x === null || x === undefined) return "—";
  if (typeof x !== "number") return String(x);
  if (Number.isInteger(x)) return x.toLocaleString("en-US");
  return Number(x.toPrecision(digits)).toString();
}
function fmtVec(v) { return "(" + v.map((x) => fmtNum(x, 4)).join(", ") + ")"; }
function fmtBytes(n) {
  if (n === null || n === undefined) return "—";
  const units = ["B", "KiB", "MiB", "GiB"];
  let i = 0;
  while (n >= 1024 && i < units.length - 1) { n /= 1024; i++; }
  return (i ? n.toFixed(1) : n) + " " + units[i];
}
function fmtSeconds(s) {
  if (s === null || s === undefined) return "—";
  if (s < 60) return s.toFixed(s < 10 ? 2 : 0) + " s";
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${Math.round(s - 60 * m)} s`;
  return `${Math.floor(m / 60)} h ${m % 60} min`;
}
function fmtTime(epoch) {
  if (!epoch) return "—";
  return new Date(epoch * 1000).toLocaleString();
}
function pct(p) { return (100 * Math.max(0, Math.min(1, p || 0))).toFixed(0) + "%"; }
function shortId(id) { return id ? id.slice(0, 8) : ""; }

function setState(node, value) {
  node.textContent = value;
  node.className = "state " + value;
  node.dataset.state = value;
}

function setBar(fill, job) {
  fill.style.width = pct(job.progress);
  fill.className = "fill " + (FINAL.has(job.state) ? job.state : "");
  fill.dataset.progress = String(job.progress);
  fill.dataset.state = job.state;
}

function countsText(counts, total) {
  const parts = [`${counts.done}/${total} done`];
  for (const name of ["running", "queued", "failed", "cancelled"]) if (counts[name]) parts.push(`${counts[name]} ${name}`);
  return parts.join(", ");
}

function parseVec(text, name, integer = false) {
  const parts = String(text || "").split(/[\s,;]+/).filter((s) => s !== "");
  const values = parts.map(Number);
  if (values.length !== 3 || values.some((v) => !Number.isFinite(v))) {
    throw new Error(`${name}: give three numbers "x, y, z", got "${text}"`);
  }
  if (integer && values.some((v) => !Number.isInteger(v))) throw new Error(`${name}: give three whole numbers, got "${text}"`);
  return values;
}

// ---------------------------------------------------------------- key and health

function applyKey(key) {
  state.key = key.trim();
  if (state.key) localStorage.setItem(KEY_STORAGE, state.key);
  else localStorage.removeItem(KEY_STORAGE);
  $("api-key").value = state.key;
  $("key-needed").hidden = !!state.key;
  showGlobalError("");
}

async function refreshHealth() {
  const node = $("health");
  try {
    const health = await (await fetch("/v1/health")).json();
    node.textContent = health.status === "ok" ? "service ok" : `degraded (database ${health.database ? "ok" : "down"}, broker ${health.broker ? "ok" : "down"})`;
    node.className = "health " + health.status;
  } catch (_) {
    node.textContent = "service unreachable";
    node.className = "health degraded";
  }
}

// ---------------------------------------------------------------- scenes

async function refreshScenes() {
  if (!state.key) return;
  const {items: scenes, total} = await apiPage("/v1/scenes?limit=1000");
  state.scenes = new Map(scenes.map((s) => [s.id, s]));
  showMore($("scenes-more"), scenes.length, total, "scenes");
  const body = $("scenes-body");
  body.replaceChildren(...scenes.map((s) => {
    const remove = el("button", {type: "button", class: "secondary small", "data-testid": "scene-delete", text: "delete"});
    remove.addEventListener("click", () => deleteScene(s));
    return el("tr", {"data-testid": "scene-row", "data-scene-id": s.id},
      el("td", {title: s.id, text: s.name}), el("td", {text: fmtNum(s.triangles)}), el("td", {text: fmtBytes(s.size_bytes)}), el("td", {}, remove));
  }));
  $("scenes-empty").hidden = scenes.length > 0;
  const select = $("job-scene");
  const previous = select.value;
  select.replaceChildren(...scenes.map((s) =>
    el("option", {value: s.id, text: `${s.name} (${shortId(s.id)}, ${fmtNum(s.triangles)} triangles)`})));
  if (!scenes.length) select.append(el("option", {value: "", text: "— upload a scene first —"}));
  if (previous && state.scenes.has(previous)) select.value = previous;
  showSceneInfo();
}

const SCENE_INFO_OBJECTS = 8;

function showSceneInfo() {
  const scene = state.scenes.get($("job-scene").value);
  const info = $("job-scene-info");
  if (!scene) { info.textContent = ""; return; }
  const [lo, hi] = scene.bounds;
  const text = (names) => `bounds ${fmtVec(lo)} – ${fmtVec(hi)}; ${fmtNum(scene.object_count)} object(s)` +
    (names ? `: ${names.join(", ")}${scene.object_count > names.length ? ", …" : ""}` : "");
  const known = state.sceneObjects.get(scene.id);
  info.textContent = text(known);
  if (known) return;
  // The first few names from the scene's paged objects route (a scene may have 10^5 objects).
  apiPage(`${scene.objects_url}?limit=${SCENE_INFO_OBJECTS}`).then(({items}) => {
    const names = items.map((o) => o.name);
    state.sceneObjects.set(scene.id, names);
    if ($("job-scene").value === scene.id) info.textContent = text(names);
  }).catch(() => {});
}

async function deleteScene(scene) {
  if (!confirm(`Delete scene ${scene.name} and its finished jobs?`)) return;
  try {
    await api(`/v1/scenes/${scene.id}`, {method: "DELETE"});
    showBox($("upload-error"), "");
  } catch (error) {
    showBox($("upload-error"), error.message);
  }
  await refreshScenes().catch(() => {});
}

async function onUpload(event) {
  event.preventDefault();
  const input = $("upload-file");
  showBox($("upload-error"), "");
  $("upload-result").hidden = true;
  if (!input.files.length) { showBox($("upload-error"), "choose a scene file first"); return; }
  const form = new FormData();
  for (const file of input.files) form.append("file", file); // several files: one scene and what it refers to
  $("upload-busy").hidden = false;
  try {
    const scene = await api("/v1/scenes", {method: "POST", form});
    const result = $("upload-result");
    result.replaceChildren(
      el("strong", {text: scene.name}), ` uploaded: ${fmtNum(scene.triangles)} triangles, ${fmtNum(scene.object_count)} object(s), `,
      `bounds ${fmtVec(scene.bounds[0])} – ${fmtVec(scene.bounds[1])}, id `, el("code", {"data-testid": "upload-scene-id", text: scene.id}),
      ...(scene.warnings || []).map((w) => el("div", {class: "warning", "data-testid": "upload-warning", text: `warning: ${w}`})));
    result.dataset.sceneId = scene.id;
    result.hidden = false;
    input.value = "";
    await refreshScenes();
    $("job-scene").value = scene.id;
    showSceneInfo();
  } catch (error) {
    showBox($("upload-error"), (error.kind ? `${error.kind}: ` : "") + error.message);
  } finally {
    $("upload-busy").hidden = true;
  }
}

// ---------------------------------------------------------------- job form

function jobMode() { return document.querySelector('#job-form input[name="mode"]:checked').value; }

function onModeChange() {
  const mode = jobMode();
  $("grid-fields").hidden = mode === "viewcells";
  $("counts-field").hidden = mode !== "grid";
  $("viewcell-fields").hidden = mode !== "viewcells";
  $("placement-fields").hidden = mode !== "placement";
  onTechniqueChange(); // a placement chooses the objects and is measured by its walkthrough: no objects, no evaluation
}

function onAlgorithmChange() {
  // The primitive-budget placement places layered depth images: technique ldi.
  if ($("job-placement-algorithm").value === "primitive-budget" && state.techniques.has("ldi")) {
    $("job-technique").value = "ldi";
    onTechniqueChange();
  }
}

function placementRequest() {
  const placement = {view_space: {lo: parseVec($("job-lo").value, "view space lo"), hi: parseVec($("job-hi").value, "view space hi")}};
  const ms = $("job-frame-ms").value.trim(), prims = $("job-primitives").value.trim();
  if ((ms === "") === (prims === "")) throw new Error("budget: give a frame budget in ms or a number of primitives, one of them");
  placement.budget = ms !== "" ? {frame_ms: numberOrText(ms)} : {primitives: numberOrText(prims)};
  placement.algorithm = $("job-placement-algorithm").value;
  const text = $("job-placement-knobs").value.trim();
  if (text !== "") {
    let knobs;
    try { knobs = JSON.parse(text); } catch (error) { throw new Error(`more knobs: not JSON (${error.message})`); }
    if (!knobs || typeof knobs !== "object" || Array.isArray(knobs)) throw new Error("more knobs: give a JSON object, e.g. {\"cpv_size\": 20}");
    Object.assign(placement, knobs);
  }
  return placement;
}

// The techniques, their image defaults and options come from GET /v1/techniques: the form has no
// per-technique code.  Each option becomes one field (integer/number: a number input with the
// bounds; boolean: a checkbox; string with choices: a select; array with choices: checkboxes).

async function refreshTechniques() {
  if (!state.key) return;
  const key = state.key;
  const body = await api("/v1/techniques");
  if (key !== state.key) return; // the key changed meanwhile: its own call fills the form
  state.techniques = new Map(body.techniques.map((t) => [t.name, t]));
  state.optionFields = new Map(); // built again for the new descriptions
  const select = $("job-technique");
  const previous = select.value;
  select.replaceChildren(...body.techniques.map((t) => el("option", {value: t.name, title: t.help, text: `${t.name} (${t.scope === "scene" ? "whole scene" : "scene's objects"})`})));
  select.disabled = body.techniques.length === 0;
  if (previous && state.techniques.has(previous)) select.value = previous;
  onTechniqueChange();
  if (state.job) renderJob(state.job); // the job page names the technique with its help
}

function technique() { return state.techniques.get($("job-technique").value) || null; }

function techniqueHelp(name) {
  const t = state.techniques.get(name);
  return t ? t.help : "";
}

function fmtDefault(value) {
  if (value === null || value === undefined) return "";
  return Array.isArray(value) ? value.join(",") : String(value);
}

function rangeText(o) {
  // "integer in [1, 1024]", "number in (0, 1]", "number > 0", ...
  const lo = o.minimum !== null ? ["[", o.minimum] : o.exclusive_minimum !== null ? ["(", o.exclusive_minimum] : null;
  const hi = o.maximum !== null ? [o.maximum, "]"] : o.exclusive_maximum !== null ? [o.exclusive_maximum, ")"] : null;
  if (lo && hi) return `${o.type} in ${lo[0]}${lo[1]}, ${hi[0]}${hi[1]}`;
  if (lo) return `${o.type} ${lo[0] === "[" ? "≥" : ">"} ${lo[1]}`;
  if (hi) return `${o.type} ${hi[1] === "]" ? "≤" : "<"} ${hi[0]}`;
  return o.type;
}

function applyBounds(input, o) {
  // Bounds as attributes where the browser can show them; the service checks them all (novalidate form).
  for (const name of ["min", "max"]) input.removeAttribute(name);
  if (o.minimum !== null && o.minimum !== undefined) input.min = String(o.minimum);
  if (o.maximum !== null && o.maximum !== undefined) input.max = String(o.maximum);
  input.step = o.type === "integer" ? "1" : "any";
}

function optionHint(o) {
  const parts = [rangeText(o)];
  if (o.choices && o.type !== "array") parts[0] = `one of ${o.choices.join(", ")}`;
  if (o.type === "array") parts[0] = o.choices ? `some of ${o.choices.join(", ")}` : "comma-separated list";
  parts.push(o.default === null ? "empty: the service decides" : `default ${fmtDefault(o.default)}`);
  return parts.join("; ");
}

function optionControl(o) {
  const attrs = {"data-testid": `option-${o.name}`, name: o.name, "data-option-type": o.type, title: o.help};
  if (o.type === "boolean") {
    const box = el("input", {...attrs, type: "checkbox"});
    box.checked = !!o.default;
    return box;
  }
  if (o.type === "array" && o.choices) {
    const group = el("span", {...attrs, class: "choices", role: "group"});
    for (const choice of o.choices) {
      const box = el("input", {type: "checkbox", value: choice});
      box.checked = Array.isArray(o.default) && o.default.includes(choice);
      group.append(el("label", {class: "inline"}, box, " " + choice));
    }
    return group;
  }
  if (o.choices) {
    const select = el("select", attrs);
    if (o.nullable) select.append(el("option", {value: "", text: "(service default)"}));
    for (const choice of o.choices) select.append(el("option", {value: choice, text: choice}));
    select.value = o.default === null ? "" : String(o.default);
    return select;
  }
  const numeric = o.type === "integer" || o.type === "number";
  const input = el("input", {...attrs, type: numeric ? "number" : "text", spellcheck: "false", placeholder: o.default === null ? "empty: the service decides" : fmtDefault(o.default)});
  if (numeric) applyBounds(input, o);
  input.value = fmtDefault(o.default);
  return input;
}

function optionFields(t) {
  // One container per technique, kept while the page lives: switching back finds the edits again.
  let box = state.optionFields.get(t.name);
  if (box) return box;
  box = el("div", {"data-testid": "option-fields", "data-technique": t.name});
  for (const o of t.options) {
    const control = optionControl(o);
    const hint = el("span", {class: "hint muted small", "data-testid": "option-help", text: `${o.help} (${optionHint(o)})`});
    const field = o.type === "boolean"
      ? el("label", {class: "option", title: o.help, "data-testid": "option-field", "data-option": o.name}, el("span", {class: "inline"}, control, " ", el("code", {text: o.name})), hint)
      : el("label", {class: "option", title: o.help, "data-testid": "option-field", "data-option": o.name}, el("code", {text: o.name}), control, hint);
    box.append(field);
  }
  state.optionFields.set(t.name, box);
  return box;
}

function applyImageDefaults(t) {
  // resolution and fov_deg take the technique's defaults unless the user typed something else.
  for (const d of t.image) {
    const input = document.querySelector(`#job-form input[name="${d.name}"]`);
    if (!input) continue;
    const value = input.value.trim();
    if (input.dataset.default === undefined || value === "" || Number(value) === Number(input.dataset.default)) input.value = fmtDefault(d.default);
    input.dataset.default = fmtDefault(d.default);
    input.placeholder = fmtDefault(d.default);
    applyBounds(input, d);
    input.title = `${d.help} (${optionHint(d)})`;
    input.closest("label").title = input.title;
  }
}

function onTechniqueChange() {
  const t = technique();
  // The whole scene, or a placement's own choice: no objects to choose (set before the techniques
  // have loaded too, so that switching to placement hides them at once).
  const scene = Boolean(t && t.scope === "scene") || jobMode() === "placement";
  $("objects-field").hidden = scene;
  $("job-objects").disabled = scene;
  $("evaluate-field").hidden = scene; // the evaluation a job records is of impostors of one part (a placement's: its walkthrough)
  $("job-evaluate").disabled = scene;
  $("technique-help").textContent = t ? t.help : "";
  $("technique-options").hidden = !t;
  if (!t) return;
  $("job-technique").title = t.help;
  $("technique-options-name").textContent = `(${t.name})`;
  $("technique-options").dataset.technique = t.name;
  $("technique-option-fields").replaceChildren(optionFields(t));
  applyImageDefaults(t);
}

function numberOrText(text) {
  // Numbers go to the server as typed (it validates and explains); anything else as the text.
  return text !== "" && Number.isFinite(Number(text)) ? Number(text) : text;
}

function sameValue(a, b) { return JSON.stringify(a) === JSON.stringify(b); }

function optionValue(o, control) {
  // The value to send, or undefined to leave the option out (the service's default).
  let value;
  if (o.type === "boolean") {
    value = control.checked;
  } else if (o.type === "array" && o.choices) {
    value = [...control.querySelectorAll("input:checked")].map((box) => box.value);
  } else {
    if (control.validity && control.validity.badInput) throw new Error(`${o.name}: give a ${o.type}`);
    const text = control.value.trim();
    if (text === "") return undefined;
    if (o.type === "array") value = text.split(/[\s,;]+/).filter(Boolean);
    else if (o.type === "integer" || o.type === "number") value = numberOrText(text);
    else value = text;
  }
  return sameValue(value, o.default) ? undefined : value;
}

function jobRequest() {
  const scene = $("job-scene").value;
  if (!scene) throw new Error("scene: upload and choose a scene first");
  const t = technique();
  if (!t) throw new Error("technique: none listed yet (GET /v1/techniques); is the API key right?");
  const request = {scene_id: scene, technique: t.name};
  const placing = jobMode() === "placement";
  if (jobMode() === "grid") {
    request.grid = {lo: parseVec($("job-lo").value, "grid lo"), hi: parseVec($("job-hi").value, "grid hi"),
                    counts: parseVec($("job-counts").value, "cells along x, y, z", true)};
  } else if (placing) {
    request.placement = placementRequest();
  } else {
    let cells;
    try { cells = JSON.parse($("job-viewcells").value); } catch (error) { throw new Error(`view cells: not JSON (${error.message})`); }
    request.viewcells = cells;
  }
  // Empty fields take the technique's defaults.
  for (const d of t.image) {
    const input = document.querySelector(`#job-form input[name="${d.name}"]`);
    if (input && input.validity.badInput) throw new Error(`${d.name}: give a ${d.type}`);
    const value = input ? input.value.trim() : "";
    if (value !== "") request[d.name] = numberOrText(value);
  }
  if (t.scope !== "scene" && !placing) {
    const objects = $("job-objects").value.split(",").map((s) => s.trim()).filter(Boolean);
    if (objects.length) request.objects = objects;
  }
  const options = {};
  const box = optionFields(t);
  for (const o of t.options) {
    const value = optionValue(o, box.querySelector(`[data-testid="option-${o.name}"]`));
    if (value !== undefined) options[o.name] = value;
  }
  if (Object.keys(options).length) request.options = options;
  if (t.scope !== "scene" && !placing && !$("job-evaluate").checked) request.evaluate = false; // on unless switched off
  return request;
}

async function onSubmitJob(event) {
  event.preventDefault();
  const box = $("job-form-error");
  showBox(box, "");
  let request;
  try {
    request = jobRequest();
  } catch (error) {
    showBox(box, error.message);
    box.dataset.source = "form";
    return;
  }
  $("job-busy").hidden = false;
  try {
    const job = await api("/v1/jobs", {method: "POST", json: request});
    location.hash = `#/jobs/${job.id}`;
  } catch (error) {
    showBox(box, (error.kind ? `${error.kind}: ` : "") + error.message);
    box.dataset.source = "server";
  } finally {
    $("job-busy").hidden = true;
  }
}

// ---------------------------------------------------------------- job list

async function refreshJobs() {
  if (!state.key) return;
  const filter = $("jobs-filter").value;
  const {items: jobs, total} = await apiPage("/v1/jobs" + (filter ? `?state=${encodeURIComponent(filter)}` : ""));
  showMore($("jobs-more"), jobs.length, total, filter ? `${filter} jobs` : "jobs");
  const body = $("jobs-body");
  const existing = new Map([...body.children].map((row) => [row.dataset.jobId, row]));
  const rows = jobs.map((job) => {
    let row = existing.get(job.id);
    if (!row) {
      row = el("tr", {"data-testid": "job-row", "data-job-id": job.id},
        el("td", {}, el("a", {href: `#/jobs/${job.id}`, "data-testid": "job-link"}, el("code", {text: shortId(job.id)}))),
        el("td", {class: "type small", "data-testid": "job-row-technique"}),
        el("td", {class: "scene"}),
        el("td", {}, el("span", {class: "state", "data-testid": "job-row-state"})),
        el("td", {}, el("div", {class: "bar", "data-testid": "job-row-progress-bar"}, el("div", {class: "fill", "data-testid": "job-row-progress"})),
          el("span", {class: "bar-label"})),
        el("td", {class: "cells", "data-testid": "job-row-counts"}),
        el("td", {class: "created small muted"}));
    }
    const [, typeCell, sceneCell, stateCell, progressCell, countsCell, createdCell] = row.children;
    const scene = state.scenes.get(job.scene_id);
    const name = job.technique || job.job_type;
    typeCell.textContent = name;
    typeCell.title = techniqueHelp(name);
    typeCell.dataset.technique = name;
    sceneCell.textContent = scene ? scene.name : shortId(job.scene_id);
    setState(stateCell.firstChild, job.state);
    setBar(progressCell.querySelector(".fill"), job);
    progressCell.querySelector(".bar-label").textContent = pct(job.progress) + (job.eta_s != null ? `, ETA ${fmtSeconds(job.eta_s)}` : "");
    countsCell.replaceChildren(countsText(job.counts, job.cells_total));
    const message = job.error || (job.errors.length ? `cell ${job.errors[0].index}: ${job.errors[0].error}` : null);
    if (message) countsCell.append(el("span", {class: "err", title: message, "data-testid": "job-row-error", text: message}));
    createdCell.textContent = fmtTime(job.created_at);
    row.dataset.state = job.state;
    return row;
  });
  // Replace the rows only when the set or order changed, so rows under the pointer stay put.
  const same = rows.length === body.children.length && rows.every((row, i) => body.children[i] === row);
  if (!same) body.replaceChildren(...rows);
  $("jobs-empty").hidden = jobs.length > 0;
}

// ---------------------------------------------------------------- job page

async function refreshJob() {
  const id = state.jobId;
  let job;
  try {
    job = await api(`/v1/jobs/${encodeURIComponent(id)}`);
  } catch (error) {
    if (id !== state.jobId) return;
    if (error.status === 404 || error.status === 422) {
      $("job-page").hidden = true;
      showBox($("job-missing"), error.message);
      return;
    }
    throw error;
  }
  if (id !== state.jobId) return; // navigated away meanwhile
  if (!state.scenes.has(job.scene_id)) await refreshScenes().catch(() => {});
  state.job = job;
  state.jobFetchedAt = Date.now();
  showBox($("job-missing"), "");
  $("job-page").hidden = false;
  renderJob(job);
}

function renderJob(job) {
  $("job-id").textContent = job.id;
  const name = job.technique || job.job_type;
  const placed = job.job_type === PLACEMENT ? (job.params || {}) : null;
  const help = !placed ? techniqueHelp(name)
    : (placed.placement || {}).algorithm === "primitive-budget" ? "layered depth images on a solution grid, so that no view draws more than the primitive budget (seed 004)"
    : `impostors of ${placed.technique} where the frame budget needs them`;
  $("job-technique-text").textContent = help ? `${name}: ${help}` : name;
  $("job-technique-text").dataset.technique = name;
  setState($("job-state"), job.state);
  setBar($("job-progress"), job);
  $("job-progress-text").textContent = pct(job.progress);
  $("job-counts-text").textContent = countsText(job.counts, job.cells_total);
  $("job-eta").textContent = FINAL.has(job.state) ? "finished" : (job.eta_s != null ? fmtSeconds(job.eta_s) : "estimating…");
  const scene = state.scenes.get(job.scene_id);
  $("job-scene-name").textContent = scene ? `${scene.name} (${shortId(scene.id)})` : job.scene_id;
  const p = job.params || {};
  const options = p.options && Object.keys(p.options).length ? `, options ${JSON.stringify(p.options)}` : "";
  const objects = p.objects ? `, objects ${p.objects.join(", ")}` : "";
  $("job-params").textContent = `${name}, ${p.resolution} px, FOV ${p.fov_deg}°${objects}${options}`;
  const s = job.seconds || {};
  $("job-times").textContent = `created ${fmtTime(job.created_at)}; wall ${fmtSeconds(s.wall)}; cells ${fmtSeconds(s.cells_total)} in all` +
    (s.cell_mean != null ? `, ${fmtSeconds(s.cell_mean)} each` : "");
  $("job-evaluation").textContent = evaluationText(job);
  $("job-cancel").disabled = FINAL.has(job.state);
  $("job-retry").disabled = job.state !== "failed";
  $("job-download").disabled = !job.has_index;
  // the 3D view (viewer.html) reads the job's index.json: there once the job has ended
  $("job-viewer").hidden = !job.has_index;
  $("job-viewer").href = `/dashboard/viewer.html?job=${encodeURIComponent(job.id)}`;
  showBox($("job-error"), job.error ? `job error: ${job.error}` : "");

  const errors = job.errors || [];
  $("job-errors-box").hidden = errors.length === 0;
  $("job-errors-count").textContent = String(errors.length);
  $("job-errors").replaceChildren(...errors.map((e) => {
    const link = el("a", {text: `cell ${e.index}`});
    link.addEventListener("click", () => selectCell(e.index, true));
    return el("li", {"data-testid": "job-error-item", "data-index": e.index}, link, `: ${e.error}`);
  }));

  renderPlacement(job);
  $("map-title").textContent = job.job_type === PLACEMENT ? "Impostors' view cells from above" : "View space from above";
  renderMap(job);
  renderCellPanel();
}

// The map: grid jobs as an nx x nz board per y level; explicit view cells as their box footprints.

function gridShape(cells) {
  if (!cells.length || cells.some((c) => !Array.isArray(c.grid))) return null;
  const n = [0, 0, 0];
  for (const c of cells) for (let a = 0; a < 3; a++) n[a] = Math.max(n[a], c.grid[a] + 1);
  return n;
}

function renderMap(job) {
  const cells = job.cells || [];
  const shape = gridShape(cells);
  const levels = shape ? shape[1] : 1;
  if (state.level >= levels) state.level = 0;
  const key = `${job.id}/${state.level}/${cells.length}`;
  if (!state.map || state.map.key !== key) buildMap(job, shape, key);
  for (const c of cells) {
    const entry = state.map.rects.get(c.index);
    if (!entry) continue;
    entry.rect.setAttribute("class", `cell ${c.state}${c.index === state.selected ? " selected" : ""}`);
    entry.rect.setAttribute("stroke-width", c.index === state.selected ? 3 : 1.5);
    entry.rect.dataset.state = c.state;
    entry.rect.dataset.progress = String(c.progress);
    entry.title.textContent = `cell ${c.index}${c.grid ? " " + fmtVec(c.grid) : ""}: ${c.state}` +
      (c.state === "running" ? ` ${pct(c.progress)}` : "") + (c.error ? ` — ${c.error}` : "");
    entry.bar.setAttribute("width", String(entry.w * (c.state === "running" ? c.progress : 0)));
  }
  const levelSelect = $("map-level");
  $("map-level-label").hidden = levels <= 1;
  if (levels > 1 && levelSelect.options.length !== levels) {
    const byLevel = new Map();
    for (const c of cells) if (!byLevel.has(c.grid[1])) byLevel.set(c.grid[1], c.viewcell);
    levelSelect.replaceChildren(...Array.from({length: levels}, (_, j) => {
      const box = byLevel.get(j);
      const range = box && box.lo ? ` (y ${fmtNum(box.lo[1], 4)} … ${fmtNum(box.hi[1], 4)})` : "";
      return el("option", {value: j, text: `${j}${range}`});
    }));
  }
  if (levels > 1) levelSelect.value = String(state.level);
}

function footprint(viewcell) {
  // [x0, z0, x1, z1] of a cell's box seen from above (other kinds by their lo/hi or centre/size if present).
  if (viewcell && viewcell.lo && viewcell.hi) return [viewcell.lo[0], viewcell.lo[2], viewcell.hi[0], viewcell.hi[2]];
  if (viewcell && viewcell.center && viewcell.size) {
    const h = viewcell.size / 2;
    return [viewcell.center[0] - h, viewcell.center[2] - h, viewcell.center[0] + h, viewcell.center[2] + h];
  }
  return null;
}

function buildMap(job, shape, key) {
  const root = $("job-map");
  const cells = (job.cells || []).filter((c) => !shape || c.grid[1] === state.level);
  const boxes = cells.map((c) => ({cell: c, box: footprint(c.viewcell)})).filter((b) => b.box);
  const scene = state.scenes.get(job.scene_id);
  const sceneBox = scene ? [scene.bounds[0][0], scene.bounds[0][2], scene.bounds[1][0], scene.bounds[1][2]] : null;
  const all = boxes.map((b) => b.box).concat(sceneBox ? [sceneBox] : []);
  root.replaceChildren();
  state.map = {key, rects: new Map()};
  if (!all.length) {
    root.setAttribute("viewBox", "0 0 400 60");
    const text = svg("text", {x: 10, y: 35, class: "axis-label", "font-size": 14});
    text.textContent = "no view cells to draw";
    root.append(text);
    return;
  }
  let [x0, z0, x1, z1] = [Infinity, Infinity, -Infinity, -Infinity];
  for (const b of all) { x0 = Math.min(x0, b[0]); z0 = Math.min(z0, b[1]); x1 = Math.max(x1, b[2]); z1 = Math.max(z1, b[3]); }
  const tiny = 1e-6 * Math.max(x1 - x0, z1 - z0, 1e-6);
  const dx = Math.max(x1 - x0, tiny), dz = Math.max(z1 - z0, tiny);
  const width = 600, margin = 36;
  const s = Math.min((width - 2 * margin) / dx, (900 - 2 * margin) / dz);
  const height = Math.max(180, dz * s + 2 * margin);
  const ox = margin + (width - 2 * margin - dx * s) / 2;
  const oz = margin / 2 + (height - 2 * margin - dz * s) / 2;
  const X = (x) => ox + (x - x0) * s;
  const Z = (z) => oz + (z - z0) * s; // z grows downwards: looking down the y axis with x to the right
  root.setAttribute("viewBox", `0 0 ${width} ${height}`);

  if (sceneBox) {
    root.append(svg("rect", {x: X(sceneBox[0]), y: Z(sceneBox[1]), width: Math.max(1, (sceneBox[2] - sceneBox[0]) * s),
      height: Math.max(1, (sceneBox[3] - sceneBox[1]) * s), class: "scene-box", "data-testid": "map-scene"}));
  }
  // Larger footprints first, so small (overlapping explicit) cells stay clickable on top.
  const area = (b) => (b[2] - b[0]) * (b[3] - b[1]);
  boxes.sort((a, b) => area(b.box) - area(a.box));
  for (const {cell, box} of boxes) {
    const x = X(box[0]), y = Z(box[1]); // grid cells share faces; the white stroke separates them
    const w = Math.max(2, (box[2] - box[0]) * s), h = Math.max(2, (box[3] - box[1]) * s);
    const group = svg("g", {});
    const rect = svg("rect", {x, y, width: w, height: h, class: `cell ${cell.state}`, "data-testid": "map-cell", "data-index": cell.index,
      "stroke-width": 1.5, "fill-opacity": shape ? 1 : 0.75});
    const title = svg("title", {});
    rect.append(title);
    rect.addEventListener("click", () => selectCell(cell.index));
    group.append(rect);
    const barHeight = Math.min(6, h / 4);
    const bar = svg("rect", {x, y: y + h - barHeight, width: 0, height: barHeight, class: "cell-progress"});
    group.append(bar);
    if (w > 28 && h > 16) {
      const label = svg("text", {x: x + 4, y: y + Math.min(15, h - 3), class: "cell-label", "font-size": Math.min(12, h / 2)});
      label.textContent = String(cell.index);
      group.append(label);
    }
    root.append(group);
    state.map.rects.set(cell.index, {rect, title, bar, w});
  }
  // Axes: x to the right, z downwards.
  const base = height - 12;
  root.append(svg("path", {d: `M 10 ${base} h 28 m -5 -4 l 5 4 l -5 4 M 10 ${base} v 0`, class: "axis"}));
  root.append(svg("path", {d: `M 10 ${base - 30} v 22 m -4 -5 l 4 5 l 4 -5`, class: "axis"}));
  const xl = svg("text", {x: 44, y: base + 4, class: "axis-label", "font-size": 11});
  xl.textContent = `x ${fmtNum(x0, 4)} … ${fmtNum(x1, 4)}`;
  const zl = svg("text", {x: 18, y: base - 20, class: "axis-label", "font-size": 11});
  zl.textContent = `z ${fmtNum(z0, 4)} … ${fmtNum(z1, 4)}`;
  root.append(xl, zl);
}

function selectCell(index, switchLevel = false) {
  state.selected = index;
  const job = state.job;
  if (switchLevel && job) {
    const cell = (job.cells || []).find((c) => c.index === index);
    if (cell && Array.isArray(cell.grid) && cell.grid[1] !== state.level) state.level = cell.grid[1];
  }
  if (job) renderMap(job);
  renderCellPanel();
}

function evaluationText(job) {
  // The job's evaluation summary (the "evaluation" of its record) in one line.
  const e = job.evaluation;
  if (job.evaluate === false) return "off for this job";
  if (techniqueScope(job.technique || job.job_type) === "scene") return "— (cells are evaluated for techniques of one part)";
  if (!e) return FINAL.has(job.state) ? "no cell evaluated" : "after each cell's bake";
  const broken = e.cells_broken ? `${e.cells_broken} breaking the guarantee` : "none breaking the guarantee";
  return `${e.cells} cells, ${broken} (${fmtNum(e.hole_pixels)} hole pixels, ${fmtNum(e.bloat_beyond_1px)} pixels bloated beyond 1 px); ` +
    `worst colour error mean ${e.colour_error_mean.toFixed(2)}, worst SSIM ${e.ssim_min.toFixed(3)}; ${fmtSeconds(e.seconds)} evaluating`;
}

function techniqueScope(name) {
  const t = state.techniques.get(name);
  return t ? t.scope : null;
}

// The figures of a cell's evaluation, in the order shown: [key in stats.evaluation, label, format].
const EVALUATION_ROWS = [
  ["hole_pixels", "hole pixels", (v) => fmtNum(v)],
  ["bloat_beyond_1px", "pixels bloated beyond 1 px", (v) => fmtNum(v)],
  ["colour_error_mean", "colour error, mean (0–255)", (v) => v.toFixed(2)],
  ["colour_error_p99", "colour error, 99th percentile", (v) => v.toFixed(1)],
  ["colour_error_1px_mean", "colour error within 1 px, mean", (v) => v.toFixed(2)],
  ["ssim", "SSIM (mean of views; 1 = equal)", (v) => v.toFixed(3)],
  ["ssim_min", "SSIM, worst view", (v) => v.toFixed(3)],
  ["viewpoints", "viewpoints × samples per pixel", (v, e) => `${v} × ${e.samples}²`],
  ["seconds", "seconds evaluating", (v) => fmtSeconds(v)],
];

function renderCellEvaluation(job, cell) {
  const e = cell.stats && cell.stats.evaluation;
  const body = $("cell-evaluation");
  const guarantee = $("cell-guarantee");
  let note = "";
  if (!e) {
    body.replaceChildren();
    guarantee.textContent = "";
    delete guarantee.dataset.guarantee;
    if (job.evaluate === false) note = "Not evaluated: switched off for this job.";
    else if (techniqueScope(job.technique || job.job_type) === "scene") note = "Not evaluated: the job report evaluates impostors of one part (layered, tdm, points).";
    else if (cell.state === "done") note = "Not evaluated.";
    else note = "Evaluated on the worker after the bake.";
    showBox($("cell-evaluation-note"), note);
    return;
  }
  const broken = e.hole_pixels > 0 || e.bloat_beyond_1px > 0;
  guarantee.textContent = broken ? "guarantee broken" : "guarantee kept";
  guarantee.dataset.guarantee = broken ? "broken" : "kept";
  guarantee.className = "guarantee " + (broken ? "broken" : "kept");
  body.replaceChildren(...EVALUATION_ROWS.filter(([key]) => typeof e[key] === "number").map(([key, label, format]) => {
    const bad = (key === "hole_pixels" || key === "bloat_beyond_1px") && e[key] > 0;
    return el("tr", {"data-figure": key, class: bad ? "bad" : null}, el("td", {text: label}), el("td", {text: format(e[key], e)}));
  }));
  note = `From the reference viewpoint and ${e.viewpoints - 1} cell corners; colour error per pixel where both cover ` +
    "(max over RGB), SSIM over both coverages. The guarantee: no hole pixel and no pixel bloated beyond 1 px.";
  showBox($("cell-evaluation-note"), note);
}

function renderCellPanel() {
  const job = state.job;
  const cell = job && state.selected !== null ? (job.cells || []).find((c) => c.index === state.selected) : null;
  $("cell-hint").hidden = !!cell;
  $("cell-body").hidden = !cell;
  const panel = $("cell-panel");
  if (!cell) {
    $("cell-title").textContent = "—";
    delete panel.dataset.index;
    return;
  }
  panel.dataset.index = String(cell.index);
  $("cell-title").textContent = `${cell.index}` + (cell.grid ? ` ${fmtVec(cell.grid)}` : "");
  setState($("cell-state"), cell.state);
  if (cell.state === "running") $("cell-state").textContent = `running ${pct(cell.progress)}`;
  const vc = cell.viewcell || {};
  $("cell-box").textContent = vc.lo ? `${vc.kind} ${fmtVec(vc.lo)} – ${fmtVec(vc.hi)}` : JSON.stringify(vc);
  $("cell-attempts").textContent = String(cell.attempts);
  const bake = cell.stats && cell.stats.seconds && typeof cell.stats.seconds.total === "number" ? cell.stats.seconds.total : null;
  const evaluating = cell.stats && cell.stats.evaluation ? cell.stats.evaluation.seconds : null;
  const parts = [bake !== null ? `bake ${fmtSeconds(bake)}` : null, evaluating != null ? `evaluation ${fmtSeconds(evaluating)}` : null].filter(Boolean);
  $("cell-seconds").textContent = fmtSeconds(cell.seconds) + (parts.length ? ` (${parts.join(", ")})` : "");
  renderCellEvaluation(job, cell);
  showBox($("cell-error"), cell.error ? cell.error : "");

  // A finished impostor may have no atlas page at all (an envmap cell that sees nothing beyond its near field).
  const statPages = cell.stats && typeof cell.stats.atlas_pages === "number" ? cell.stats.atlas_pages : null;
  const pages = statPages !== null ? statPages : (cell.has_result ? 1 : 0);
  const pageSelect = $("cell-page");
  if (pageSelect.options.length !== pages || pageSelect.dataset.cell !== String(cell.index)) {
    pageSelect.replaceChildren(...Array.from({length: pages}, (_, i) => el("option", {value: i, text: String(i)})));
    pageSelect.dataset.cell = String(cell.index);
  }
  pageSelect.disabled = pages <= 1;
  for (const button of document.querySelectorAll("#cell-panel [data-download]")) button.disabled = !cell.has_result;
  const inside = $("cell-viewer");
  inside.hidden = !(cell.has_result && job.has_index && cell.viewcell && cell.viewcell.kind === "box");
  inside.href = `/dashboard/viewer.html?job=${encodeURIComponent(job.id)}&cell=${cell.index}`;

  const stats = $("cell-stats");
  const statsKey = `${job.id}/${cell.index}/${JSON.stringify(cell.stats)}`;
  if (stats.dataset.key !== statsKey) {
    const rows = [];
    const walk = (prefix, value) => {
      if (value && typeof value === "object" && !Array.isArray(value)) {
        for (const [k, v] of Object.entries(value)) walk(prefix ? `${prefix}.${k}` : k, v);
        return;
      }
      let text = Array.isArray(value) ? value.map((v) => fmtNum(v, 4)).join(" × ") : fmtNum(value, 4);
      if (/bytes/.test(prefix) && typeof value === "number") text = fmtBytes(value);
      if (/^seconds\./.test(prefix) && typeof value === "number") text = fmtSeconds(value);
      rows.push(el("tr", {"data-stat": prefix}, el("td", {text: prefix}), el("td", {text})));
    };
    const {evaluation: _shownAbove, ...rest} = cell.stats || {}; // the evaluation has its own table
    walk("", rest);
    if (!rows.length) rows.push(el("tr", {}, el("td", {class: "muted", text: "no statistics yet"}), el("td", {})));
    stats.replaceChildren(...rows);
    stats.dataset.key = statsKey;
  }
  loadAtlas(job, cell, Number(pageSelect.value || 0), pages);
}

async function loadAtlas(job, cell, page, pages) {
  const img = $("cell-atlas");
  const note = $("cell-atlas-note");
  if (!cell.has_result) {
    state.atlas.key = null;
    img.hidden = true;
    img.removeAttribute("src");
    note.textContent = cell.state === "failed" || cell.state === "cancelled" ? `no impostor (cell ${cell.state})` : `no impostor yet (cell ${cell.state})`;
    return;
  }
  if (pages === 0) {
    state.atlas.key = null;
    img.hidden = true;
    img.removeAttribute("src");
    note.textContent = cell.stats && cell.stats.near_field !== undefined
      ? "no atlas pages: everything this cell sees lies in its near field (drawn as polygons)"
      : "no atlas pages: the impostor kept no texels";
    return;
  }
  const key = `${job.id}/${cell.index}/${page}`;
  if (state.atlas.key === key) return;
  state.atlas.key = key;
  img.hidden = true;
  note.textContent = "loading atlas…";
  try {
    const response = await api(`/v1/jobs/${job.id}/cells/${cell.index}/atlas/${page}.png`, {raw: true});
    const blob = await response.blob();
    if (state.atlas.key !== key) return; // another cell was clicked meanwhile
    if (state.atlas.url) URL.revokeObjectURL(state.atlas.url);
    state.atlas.url = URL.createObjectURL(blob);
    img.onload = () => {
      if (state.atlas.key !== key) return;
      note.textContent = "";
      img.hidden = false;
      img.title = `atlas page ${page}: ${img.naturalWidth} × ${img.naturalHeight}`;
    };
    img.onerror = () => { if (state.atlas.key === key) note.textContent = "the atlas page did not decode"; };
    img.dataset.cell = String(cell.index);
    img.dataset.page = String(page);
    img.src = state.atlas.url;
  } catch (error) {
    if (state.atlas.key === key) {
      state.atlas.key = null;
      note.textContent = `atlas: ${error.message}`;
    }
  }
}

// ---------------------------------------------------------------- placement jobs

// While it places: the planner's step and counts (the job record's "placement"); once its database is
// written: GET /v1/jobs/{id}/placement (fetched once per end of the job), drawn as a map of its CPVs'
// regions over the view space's two longest axes, coloured by their worst estimated time against t_max.

function renderPlacement(job) {
  const panel = $("placement-panel");
  panel.hidden = job.job_type !== PLACEMENT;
  if (panel.hidden) return;
  const planning = job.placement || null;
  const box = $("placement-planning");
  box.hidden = !(job.state === "placing" || (planning && !job.has_index && !FINAL.has(job.state)));
  if (!box.hidden) {
    const p = planning || {};
    const total = Number(p.total) || 0, done = Number(p.done) || 0;
    const fill = $("placement-planning-bar");
    fill.style.width = pct(total ? done / total : 0);
    fill.className = "fill";
    for (const k of ["step", "done", "total", "round"]) box.dataset[k] = p[k] === undefined || p[k] === null ? "" : String(p[k]);
    $("placement-planning-text").textContent = planning
      ? `planning: ${p.step || "starting"}, ${fmtNum(done)}/${fmtNum(total)}` + (p.round ? `, check-and-repair round ${p.round}` : "")
      : "planning: waiting for a worker";
  }
  let note = "";
  if (!job.has_index) {
    note = job.state === "placing" ? "The map of the view space comes when the planned impostors are baked."
      : FINAL.has(job.state) ? `No placement database: the job is ${job.state}.` : `Baking the planned impostors (${countsText(job.counts, job.cells_total)}).`;
  } else if (state.placement.error) {
    note = `placement: ${state.placement.error}`;
  }
  showBox($("placement-note"), note);
  $("placement-colour-label").hidden = !job.has_index;
  if (!job.has_index) {
    $("placement-body").hidden = true;
    return;
  }
  const key = `${job.id}/${job.finished_at}`;
  if (state.placement.key !== key) {
    state.placement = {key, doc: null, error: null};
    loadPlacement(job, key);
    return;
  }
  if (state.placement.doc) drawPlacement(state.placement.doc);
}

async function loadPlacement(job, key) {
  try {
    const doc = await api(`/v1/jobs/${encodeURIComponent(job.id)}/placement`);
    if (state.placement.key !== key) return;
    state.placement.doc = doc;
  } catch (error) {
    if (state.placement.key !== key) return;
    state.placement.error = error.message;
  }
  if (state.job && state.job.id === job.id) renderPlacement(state.job);
}

function mapAxes(lo, hi) {
  // The view space's two longest axes, in axis order: the first to the right, the second downwards.
  const order = [0, 1, 2].sort((a, b) => (hi[b] - lo[b]) - (hi[a] - lo[a]) || a - b);
  return order.slice(0, 2).sort((a, b) => a - b);
}

const STATUS_RANK = {solved: 0, unsolved: 1, unsolvable: 2};

function placementRegions(doc, axes) {
  // CPVs grouped by their region's footprint on the map (regions stacked along the third axis share one).
  const [a, b] = axes;
  const groups = new Map();
  for (const cpv of doc.cpvs) {
    const [lo, hi] = cpv.region;
    const box = [lo[a], lo[b], hi[a], hi[b]];
    const key = box.join(",");
    if (!groups.has(key)) groups.set(key, {key, box, cpvs: [], regions: new Set(), before: -Infinity, after: -Infinity, status: "solved"});
    const g = groups.get(key);
    g.cpvs.push(cpv);
    g.regions.add(JSON.stringify(cpv.region));
    g.before = Math.max(g.before, cpv.time_before);
    g.after = Math.max(g.after, cpv.time_after);
    if (STATUS_RANK[cpv.status] > STATUS_RANK[g.status]) g.status = cpv.status;
  }
  return [...groups.values()];
}

function timeColour(ratio) {
  // Green, lighter the further under t_max; orange to red over it.
  if (ratio <= 1) return `hsl(120, 45%, ${Math.round(80 - 38 * Math.max(0, ratio))}%)`;
  return `hsl(${Math.round(40 - 40 * Math.min(1, ratio - 1))}, 80%, 52%)`;
}

const FACTS = ["budget", "impostors", "memory", "cpvs", "unsolvable", "rounds"];

function factLabels(labels) {
  // The totals' labels: a primitive-budget placement has grid points where a frame-time one has CPVs.
  for (const k of FACTS) $(`placement-${k}-label`).textContent = (labels && labels[k]) || $(`placement-${k}-label`).dataset.label;
}

function drawPlacement(doc) {
  $("placement-body").hidden = false;
  const images = doc.algorithm === "primitive-budget";
  $("placement-colour-label").hidden = images;
  $("placement-legend").hidden = images;
  $("placement-point-legend").hidden = !images;
  $("region-panel").hidden = images;
  if (images) return drawImagePlacement(doc);
  factLabels(null);
  const t = doc.totals, s = doc.summary, unit = s.unit;
  const tMax = doc.parameters.t_max;
  $("placement-budget").textContent = `t_max ${fmtNum(tMax, 4)} ${unit} (cost model: ${doc.parameters.cost_model.kind || doc.parameters.cost_model.source || "given"}); ` +
    `worst CPV ${fmtNum(s.worst_before, 4)} → ${fmtNum(s.worst_after, 4)} ${unit}`;
  $("placement-impostors").textContent = `${fmtNum(t.impostors)} drawn (${fmtNum(t.impostors_baked)} of ${fmtNum(t.impostors_listed)} baked), ${doc.parameters.technique}`;
  $("placement-memory").textContent = `${fmtBytes(t.memory_bytes_baked)} baked, ${fmtBytes(Math.round(t.memory_bytes_estimated))} estimated`;
  $("placement-memory").dataset.baked = String(t.memory_bytes_baked);
  const by = t.cpvs_by_status;
  $("placement-cpvs").textContent = `${fmtNum(t.cpvs)} (${fmtNum(by.solved)} solved, ${fmtNum(by.unsolved)} unsolved, ${fmtNum(by.unsolvable)} unsolvable)`;
  $("placement-unsolvable").textContent = t.unsolvable_regions ? `${fmtNum(t.unsolvable_regions)} region(s) where the geometry no impostor may replace exceeds t_max alone` : "no region";
  $("placement-unsolvable").dataset.regions = String(t.unsolvable_regions);
  $("placement-rounds").textContent = `${fmtNum(t.rounds)} check-and-repair round(s) after the first bake`;

  const [lo, hi] = doc.parameters.view_space;
  const axes = mapAxes(lo, hi);
  const names = "xyz";
  const mapKey = `${state.placement.key}/${state.colour}/${state.region}`;
  const root = $("placement-map");
  if (root.dataset.key === mapKey) return;
  root.dataset.key = mapKey;
  root.dataset.colour = state.colour;
  const [a, b] = axes;
  const x0 = lo[a], z0 = lo[b], dx = Math.max(hi[a] - lo[a], 1e-9), dz = Math.max(hi[b] - lo[b], 1e-9);
  const width = 600, margin = 30;
  const scale = Math.min((width - 2 * margin) / dx, (700 - 2 * margin) / dz);
  const height = dz * scale + 2 * margin;
  const X = (v) => margin + (v - x0) * scale;
  const Z = (v) => margin + (v - z0) * scale;
  root.setAttribute("viewBox", `0 0 ${width} ${height}`);
  const nodes = [svg("rect", {x: X(lo[a]), y: Z(lo[b]), width: dx * scale, height: dz * scale, class: "view-space", "data-testid": "placement-view-space"})];
  const groups = placementRegions(doc, axes);
  const area = (g) => (g.box[2] - g.box[0]) * (g.box[3] - g.box[1]);
  groups.sort((p, q) => area(q) - area(p)); // small regions on top, clickable
  for (const g of groups) {
    const time = state.colour === "before" ? g.before : g.after;
    const ratio = time / tMax;
    const over = ratio > 1 + 1e-9;
    const rect = svg("rect", {
      x: X(g.box[0]), y: Z(g.box[1]), width: Math.max(2, (g.box[2] - g.box[0]) * scale), height: Math.max(2, (g.box[3] - g.box[1]) * scale),
      class: "region" + (g.key === state.region ? " selected" : ""), fill: timeColour(ratio), "data-testid": "placement-region",
      "data-key": g.key, "data-cpvs": String(g.cpvs.length), "data-time": String(time), "data-over": String(over), "data-status": g.status,
    });
    const title = svg("title", {});
    title.textContent = `${names[a]} ${fmtNum(g.box[0], 4)} … ${fmtNum(g.box[2], 4)}, ${names[b]} ${fmtNum(g.box[1], 4)} … ${fmtNum(g.box[3], 4)}: ` +
      `${g.cpvs.length} CPV(s), worst ${fmtNum(time, 4)} ${unit} ${state.colour} placement (t_max ${fmtNum(tMax, 4)}), ${g.status}`;
    rect.append(title);
    rect.addEventListener("click", () => selectRegion(g.key));
    nodes.push(rect);
  }
  for (const u of doc.unsolvable || []) {
    const [ulo, uhi] = u.region;
    nodes.push(svg("rect", {x: X(ulo[a]), y: Z(ulo[b]), width: Math.max(2, (uhi[a] - ulo[a]) * scale), height: Math.max(2, (uhi[b] - ulo[b]) * scale),
      class: "unsolvable-region", "data-testid": "placement-unsolvable-region"}));
  }
  root.replaceChildren(...nodes);
  $("placement-axes").textContent = `${names[a]} ${fmtNum(lo[a], 4)} … ${fmtNum(hi[a], 4)} to the right, ${names[b]} ${fmtNum(lo[b], 4)} … ${fmtNum(hi[b], 4)} downwards ` +
    `(the view space's two longest axes; regions stacked along ${names[3 - a - b]} are drawn as one, with their worst time). Click a region.`;
  renderRegion(doc, groups.find((g) => g.key === state.region) || null);
}

function drawImagePlacement(doc) {
  // Seed 004's solution grid: its points over the view space's two longest axes, marked by whether
  // their views warp LDI images; the budget, the images and the check of the guarantee.
  factLabels({cpvs: "grid points", unsolvable: "unsolved", rounds: "check"});
  const t = doc.totals, s = doc.summary, par = doc.parameters, check = s.check;
  $("placement-budget").textContent = `P ${fmtNum(par.primitives)} triangles a view (p_opt ${fmtNum(par.p_opt)}; the model ${fmtNum(s.model_triangles)}), FOV ${fmtNum(par.fov_deg)}°`;
  $("placement-impostors").textContent = `${fmtNum(t.images)} LDI images (${fmtNum(t.images_baked)} baked, ${par.construction_images} construction images, ${par.resolution} px), ldi`;
  $("placement-memory").textContent = `${fmtBytes(t.memory_bytes_baked)} baked`;
  $("placement-memory").dataset.baked = String(t.memory_bytes_baked);
  $("placement-cpvs").textContent = `${fmtNum(t.grid_points)} (per level: ${s.points_per_level.join(" / ")})`;
  $("placement-unsolvable").textContent = t.unsolved_points ? `${fmtNum(t.unsolved_points)} grid point(s) over P at the deepest level` : "no grid point";
  $("placement-unsolvable").dataset.regions = String(t.unsolved_points);
  $("placement-rounds").textContent = check
    ? `${fmtNum(check.views)} random views: ${fmtNum(100 * check.within_p, 4)} % within P, at most ${fmtNum(check.max)} triangles (p99 ${fmtNum(check.p99)})`
    : "not checked (check_views 0)";
  const [lo, hi] = par.view_space;
  const axes = mapAxes(lo, hi);
  const names = "xyz";
  const root = $("placement-map");
  if (root.dataset.key === state.placement.key) return;
  root.dataset.key = state.placement.key;
  const [a, b] = axes;
  const reach = doc.points.reduce((m, p) => Math.max(m, p.radius), 0);
  const x0 = lo[a] - reach, z0 = lo[b] - reach, dx = Math.max(hi[a] - lo[a] + 2 * reach, 1e-9), dz = Math.max(hi[b] - lo[b] + 2 * reach, 1e-9);
  const width = 600, margin = 30;
  const scale = Math.min((width - 2 * margin) / dx, (700 - 2 * margin) / dz);
  const X = (v) => margin + (v - x0) * scale;
  const Z = (v) => margin + (v - z0) * scale;
  root.setAttribute("viewBox", `0 0 ${width} ${dz * scale + 2 * margin}`);
  const nodes = [svg("rect", {x: X(lo[a]), y: Z(lo[b]), width: Math.max(2, (hi[a] - lo[a]) * scale), height: Math.max(2, (hi[b] - lo[b]) * scale),
    class: "view-space", "data-testid": "placement-view-space"})];
  doc.points.forEach((p, i) => {
    const kind = p.failure ? "unsolved" : p.images.length ? "images" : "geometry";
    const dot = svg("circle", {cx: X(p.position[a]), cy: Z(p.position[b]), r: p.images.length ? 4 : 2.5,
      fill: kind === "unsolved" ? timeColour(2) : kind === "images" ? timeColour(0.95) : timeColour(0.2),
      "data-testid": "placement-point", "data-index": String(i), "data-images": String(p.images.length), "data-kind": kind});
    const title = svg("title", {});
    title.textContent = `grid point ${i} at ${fmtVec(p.position)}, level ${p.level}: ${p.images.length} image(s)` +
      (p.images.length ? ` (${p.images.map((im) => `${im.name}: cell ${im.cell}, ${fmtNum(im.drawn)} triangles drawn`).join("; ")})` : "") +
      (p.failure ? `; unsolved: ${p.failure}` : "");
    dot.append(title);
    nodes.push(dot);
  });
  root.replaceChildren(...nodes);
  $("placement-axes").textContent = `${names[a]} to the right, ${names[b]} downwards (the view space's two longest axes; points stacked along ` +
    `${names[3 - a - b]} are drawn on top of each other). Each grid point's images replace one subset of the model in the views of one range of yaw.`;
}

function selectRegion(key) {
  state.region = key;
  if (state.placement.doc) drawPlacement(state.placement.doc);
}

function renderRegion(doc, group) {
  const panel = $("region-panel");
  $("region-hint").hidden = !!group;
  $("region-body").hidden = !group;
  if (!group) {
    $("region-title").textContent = "—";
    delete panel.dataset.key;
    return;
  }
  panel.dataset.key = group.key;
  const tMax = doc.parameters.t_max, unit = doc.summary.unit;
  const regions = [...group.regions].map((r) => JSON.parse(r));
  $("region-title").textContent = regions.map(([lo, hi]) => `${fmtVec(lo)} – ${fmtVec(hi)}`).join("; ") + ` (${group.cpvs.length} CPVs, times in ${unit})`;
  const cells = new Map(doc.cells.map((c) => [c.index, c]));
  const impostorLink = (i) => {
    const link = el("a", {text: `#${i}`, "data-testid": "region-cpv-impostor", "data-index": i});
    link.addEventListener("click", () => selectCell(i, true));
    return link;
  };
  $("region-cpvs").replaceChildren(...group.cpvs.map((cpv) => {
    const v = cpv.vdi;
    const links = el("td", {});
    cpv.impostors.forEach((i, n) => { if (n) links.append(" "); links.append(impostorLink(i)); });
    if (!cpv.impostors.length) links.append("none");
    return el("tr", {"data-testid": "region-cpv", "data-cpv": cpv.id, "data-status": cpv.status},
      el("td", {text: String(cpv.id)}), el("td", {text: `${v.face} level ${v.level} (${v.i}, ${v.j})`}),
      el("td", {text: fmtNum(cpv.time_before, 4), class: cpv.time_before > tMax ? "over" : null}),
      el("td", {text: fmtNum(cpv.time_after, 4), class: cpv.time_after > tMax * (1 + 1e-9) ? "over" : null}),
      el("td", {}, el("span", {class: "state " + (cpv.status === "solved" ? "done" : "failed"), text: cpv.status})), links);
  }));
  const drawn = [...new Set(group.cpvs.flatMap((cpv) => cpv.impostors))].sort((p, q) => p - q);
  $("region-impostors").replaceChildren(...drawn.map((i) => {
    const cell = cells.get(i) || {objects: [], figures: {}};
    const baked = (cell.figures && cell.figures.baked) || {};
    const link = el("a", {text: `impostor ${i}`});
    link.addEventListener("click", () => selectCell(i, true));
    return el("li", {"data-testid": "region-impostor", "data-index": i}, link,
      ` (${cell.technique || "?"}${baked.texture_bytes !== undefined ? ", " + fmtBytes(baked.texture_bytes) : ""}) replaces `,
      el("span", {"data-testid": "region-impostor-objects", text: cell.objects.join(", ")}));
  }));
}

async function jobAction(action) {
  const box = $("job-action-error");
  showBox(box, "");
  try {
    const job = await api(`/v1/jobs/${state.jobId}/${action}`, {method: "POST"});
    state.job = job;
    state.jobFetchedAt = Date.now();
    renderJob(job);
  } catch (error) {
    showBox(box, `${action}: ${error.message}`);
  }
}

// ---------------------------------------------------------------- routing and polling

function route() {
  const match = location.hash.match(/^#\/jobs\/([^/?#]+)/);
  const jobId = match ? decodeURIComponent(match[1]) : null;
  state.view = jobId ? "job" : "home";
  $("view-home").hidden = state.view !== "home";
  $("view-job").hidden = state.view !== "job";
  if (jobId !== state.jobId) {
    state.jobId = jobId;
    state.job = null;
    state.map = null;
    state.level = 0;
    state.selected = null;
    state.atlas.key = null;
    state.placement = {key: null, doc: null, error: null};
    state.region = null;
    $("placement-map").replaceChildren();
    $("job-page").hidden = true;
    showBox($("job-action-error"), "");
    $("cell-page").replaceChildren();
    $("map-level").replaceChildren();
    $("cell-stats").replaceChildren();
    delete $("cell-stats").dataset.key;
  }
  tick(true);
}

async function tick(force = false) {
  if (!state.key || (document.hidden && !force)) return; // no polling from a background tab
  if (state.polling) {
    if (force) setTimeout(() => tick(true), 100); // a navigation must not be lost behind a poll
    return;
  }
  state.polling = true;
  try {
    if (state.view === "home") {
      await refreshJobs();
    } else if (state.jobId) {
      const finished = state.job && FINAL.has(state.job.state);
      if (force || !finished || Date.now() - state.jobFetchedAt > 5000) await refreshJob();
    }
    if ($("global-error").textContent.startsWith("cannot reach")) showGlobalError("");
  } catch (error) {
    if (error.status !== 401) showGlobalError(error.message);
  } finally {
    state.polling = false;
  }
}

function start() {
  $("api-key").value = state.key;
  $("key-needed").hidden = !!state.key;
  $("key-form").addEventListener("submit", async (event) => {
    event.preventDefault();
    applyKey($("api-key").value);
    await refreshScenes().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
    refreshTechniques().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
    tick(true);
  });
  $("key-forget").addEventListener("click", () => applyKey(""));
  $("upload-form").addEventListener("submit", onUpload);
  $("job-form").addEventListener("submit", onSubmitJob);
  $("job-placement-algorithm").addEventListener("change", onAlgorithmChange);
  $("job-technique").addEventListener("change", onTechniqueChange);
  for (const radio of document.querySelectorAll('#job-form input[name="mode"]')) radio.addEventListener("change", onModeChange);
  $("job-scene").addEventListener("change", showSceneInfo);
  $("jobs-filter").addEventListener("change", () => tick(true));
  $("map-level").addEventListener("change", () => { state.level = Number($("map-level").value); if (state.job) renderMap(state.job); });
  $("cell-page").addEventListener("change", () => renderCellPanel());
  $("placement-colour").addEventListener("change", () => {
    state.colour = $("placement-colour").value;
    if (state.job) renderPlacement(state.job);
  });
  $("job-cancel").addEventListener("click", () => jobAction("cancel"));
  $("job-retry").addEventListener("click", () => jobAction("retry"));
  $("job-download").addEventListener("click", () => download(`/v1/jobs/${state.jobId}/database.zip`, `job-${state.jobId}.zip`));
  for (const button of document.querySelectorAll("#cell-panel [data-download]")) {
    button.addEventListener("click", () => {
      const name = button.dataset.download;
      const ext = name.split(".").pop();
      download(`/v1/jobs/${state.jobId}/cells/${state.selected}/${name}`, `cell-${String(state.selected).padStart(5, "0")}.${ext}`);
    });
  }
  window.addEventListener("hashchange", route);
  refreshHealth();
  setInterval(refreshHealth, 10000);
  if (state.key) {
    refreshScenes().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
    refreshTechniques().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
  }
  route();
  setInterval(() => tick(false), POLL_MS);
}

start();
