// A job's page: its record, the map of its view cells, the selected cell's panel (evaluation,
// statistics, atlas page) and the job's actions.

import {api, download} from "./api.js";
import {FINAL, partTechniques, PLACEMENT, placementAlgorithm, state, techniqueHelp, techniqueScope} from "./state.js";
import {$, el, setBar, setState, showBox, svg} from "./dom.js";
import {admitting, countsText, fmtBytes, fmtNum, fmtSeconds, fmtTime, fmtVec, pct, shortId} from "./format.js";
import {refreshScenes} from "./scenes.js";
import {renderPlacement} from "./placement.js";

// A job of more cells than this is polled without its cells (GET /v1/jobs/{id}?cells=none: counts,
// progress, errors from SQL), its whole record (cells, evaluation, timing) fetched at most every
// CELLS_EVERY_MS, and once more when its state changes: a 1,000-cell job's record every second took
// most of the API's time (issue 58).
const FEW_CELLS = 200;
const CELLS_EVERY_MS = 5000;

async function fetchJob(id) {
  const path = `/v1/jobs/${encodeURIComponent(id)}`;
  const old = state.job && state.job.id === id ? state.job : null;
  if (!old || old.cells_total <= FEW_CELLS) return api(path);
  const brief = await api(`${path}?cells=none`);
  if (brief.state !== old.state || brief.cells_total <= FEW_CELLS || Date.now() - state.jobCellsAt > CELLS_EVERY_MS) return api(path);
  return {...brief, cells: old.cells, evaluation: old.evaluation, timing: old.timing};
}

export async function refreshJob() {
  const id = state.jobId;
  let job;
  try {
    job = await fetchJob(id);
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
  if (job !== state.job && (!state.job || job.cells !== state.job.cells)) state.jobCellsAt = Date.now();
  state.job = job;
  state.jobFetchedAt = Date.now();
  showBox($("job-missing"), "");
  $("job-page").hidden = false;
  renderJob(job);
}

export function renderJob(job) {
  $("job-id").textContent = job.id;
  const name = job.technique || job.job_type;
  const placed = job.job_type === PLACEMENT ? (job.params || {}) : null;
  const algorithm = placed ? placementAlgorithm((placed.placement || {}).algorithm) : null;
  const help = !placed ? techniqueHelp(name) : algorithm ? algorithm.summary.replaceAll("{technique}", placed.technique) : "";
  $("job-technique-text").textContent = help ? `${name}: ${help}` : name;
  $("job-technique-text").dataset.technique = name;
  setState($("job-state"), job.state);
  setBar($("job-progress"), job); // the cells' progress: 0 while they are checked
  const checking = admitting(job); // its cells' full checks, before any is baked
  $("job-progress-text").textContent = checking ? checking.text : pct(job.progress);
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
  renderTiming(job.timing);
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

export function renderMap(job) {
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

export function selectCell(index, switchLevel = false) {
  state.selected = index;
  const job = state.job;
  if (switchLevel && job) {
    const cell = (job.cells || []).find((c) => c.index === index);
    if (cell && Array.isArray(cell.grid) && cell.grid[1] !== state.level) state.level = cell.grid[1];
  }
  if (job) renderMap(job);
  renderCellPanel();
}

// The job's time broken down (its record's "timing"), as [label, seconds] rows; the bake's stages
// are summed over the cells, inside "cells".
function timingRows(t) {
  const rows = [["wall", t.wall_s]];
  for (const name of ["admission", "planning"]) if (t[`${name}_s`]) rows.push([name, t[`${name}_s`]]);
  const busy = t.cells_busy_s > 0 ? ` (busy ${fmtSeconds(t.cells_busy_s)})` : "";
  rows.push([`cells (${t.cells}, summed)${busy}`, t.cells_s]);
  for (const [stage, seconds] of Object.entries(t.stages || {})) rows.push([`bake: ${stage}`, seconds]);
  if (t.evaluation_s) rows.push(["evaluation", t.evaluation_s]);
  if (t.checking_s) rows.push(["checking", t.checking_s]);
  rows.push(["overhead", t.overhead_s]);
  return rows;
}

function renderTiming(timing) {
  $("job-timing-box").hidden = !timing;
  if (!timing) return;
  $("job-timing").replaceChildren(...timingRows(timing).map(([label, seconds]) =>
    el("tr", {"data-testid": "job-timing-row"}, el("td", {text: label}), el("td", {text: fmtSeconds(seconds)}))));
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

function partList() {
  // " (layered, tdm, ...)": the techniques of one part, as GET /v1/techniques lists them
  const names = partTechniques();
  return names.length ? ` (${names.join(", ")})` : "";
}

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
    else if (techniqueScope(job.technique || job.job_type) === "scene") note = `Not evaluated: the job report evaluates impostors of one part${partList()}.`;
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

export function renderCellPanel() {
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

export async function jobAction(action) {
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

// A job's or a cell's file (the database zip, a bundle, ...), saved by the browser.
export async function saveFile(path, filename) {
  try {
    await download(path, filename);
  } catch (error) {
    showBox($("job-action-error"), `download failed: ${error.message}`);
  }
}
