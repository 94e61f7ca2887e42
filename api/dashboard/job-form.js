// The job form: a grid, explicit view cells or a placement; the technique and its options, all
// from GET /v1/techniques.

import {api, apiKey, fetchPlacementAlgorithms, fetchTechniques} from "./api.js";
import {placementAlgorithm, state} from "./state.js";
import {$, el, showBox} from "./dom.js";
import {parseVec} from "./format.js";
import {renderJob} from "./job.js";

function jobMode() { return document.querySelector('#job-form input[name="mode"]:checked').value; }

export function onModeChange() {
  const mode = jobMode();
  $("grid-fields").hidden = mode === "viewcells";
  $("counts-field").hidden = mode !== "grid";
  $("viewcell-fields").hidden = mode !== "viewcells";
  $("placement-fields").hidden = mode !== "placement";
  onTechniqueChange(); // a placement chooses the objects and is measured by its walkthrough: no objects, no evaluation
}

export function onAlgorithmChange() {
  // An algorithm that bakes one technique (GET /v1/placement-algorithms: its "technique") switches the form to it.
  const algorithm = placementAlgorithm($("job-placement-algorithm").value);
  if (algorithm && algorithm.technique && state.techniques.has(algorithm.technique)) {
    $("job-technique").value = algorithm.technique;
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

export async function refreshTechniques() {
  if (!apiKey()) return;
  const key = apiKey();
  const [techniques, algorithms] = await Promise.all([fetchTechniques(), fetchPlacementAlgorithms()]);
  if (key !== apiKey()) return; // the key changed meanwhile: its own call fills the form
  state.techniques = techniques;
  state.algorithms = algorithms.algorithms;
  state.defaultAlgorithm = algorithms.default;
  const algorithmSelect = $("job-placement-algorithm");
  const chosen = algorithmSelect.value;
  algorithmSelect.replaceChildren(...[...algorithms.algorithms.values()].map((a) => el("option", {value: a.name, title: a.help, text: `${a.name} ${a.choice}`})));
  algorithmSelect.value = chosen && algorithms.algorithms.has(chosen) ? chosen : algorithms.default;
  state.optionFields = new Map(); // built again for the new descriptions
  const select = $("job-technique");
  const previous = select.value;
  select.replaceChildren(...[...techniques.values()].map((t) => el("option", {value: t.name, title: t.help, text: `${t.name} (${t.scope === "scene" ? "whole scene" : "scene's objects"})`})));
  select.disabled = techniques.size === 0;
  if (previous && state.techniques.has(previous)) select.value = previous;
  onTechniqueChange();
  if (state.job) renderJob(state.job); // the job page names the technique with its help
}

function technique() { return state.techniques.get($("job-technique").value) || null; }

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

export function onTechniqueChange() {
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

export async function onSubmitJob(event) {
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

