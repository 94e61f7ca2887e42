// A placement job's part of the job page.

import {api} from "./api.js";
import {FINAL, PLACEMENT, placementAlgorithm, state} from "./state.js";
import {$, el, showBox, svg} from "./dom.js";
import {countsText, fmtBytes, fmtNum, fmtVec, pct} from "./format.js";
import {selectCell} from "./job.js";

// While it places: the planner's step and counts (the job record's "placement"); once its database is
// written: GET /v1/jobs/{id}/placement (fetched once per end of the job), drawn as a map of its CPVs'
// regions over the view space's two longest axes, coloured by their worst estimated time against t_max.

export function renderPlacement(job) {
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
  // The totals' labels: an algorithm's own (GET /v1/placement-algorithms: "labels", e.g. grid points for CPVs), else the page's.
  for (const k of FACTS) $(`placement-${k}-label`).textContent = (labels && labels[k]) || $(`placement-${k}-label`).dataset.label;
}

function drawPlacement(doc) {
  const algorithm = placementAlgorithm(doc.algorithm);
  $("placement-body").hidden = !algorithm;
  if (!algorithm) return; // GET /v1/placement-algorithms not answered yet: drawn when it is
  const images = algorithm.images;
  $("placement-colour-label").hidden = images;
  $("placement-legend").hidden = images;
  $("placement-point-legend").hidden = !images;
  $("region-panel").hidden = images;
  factLabels(algorithm.labels);
  if (images) return drawImagePlacement(doc);
  const t = doc.totals, s = doc.summary, unit = s.unit;
  const tMax = doc.parameters.t_max;
  $("placement-budget").textContent = `t_max ${fmtNum(tMax, 4)} ${unit} (cost model: ${doc.parameters.cost_model.kind || doc.parameters.cost_model.source || "given"}); ` +
    `worst CPV ${fmtNum(s.worst_before, 4)} → ${fmtNum(s.worst_after, 4)} ${unit}`;
  // Mixed candidates (also / lod): how many of each kind were chosen, and their memory (totals.by_technique).
  const kinds = t.by_technique ? "; " + Object.entries(t.by_technique)
    .map(([name, row]) => `${name} ${fmtNum(row.impostors)} (${fmtBytes(row.memory_bytes_baked || Math.round(row.memory_bytes_estimated))})`).join(", ") : "";
  $("placement-impostors").textContent = `${fmtNum(t.impostors)} drawn (${fmtNum(t.impostors_baked)} of ${fmtNum(t.impostors_listed)} baked), ${doc.parameters.technique}${kinds}`;
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
  const t = doc.totals, s = doc.summary, par = doc.parameters, check = s.check;
  $("placement-budget").textContent = `P ${fmtNum(par.primitives)} triangles a view (p_opt ${fmtNum(par.p_opt)}; the model ${fmtNum(s.model_triangles)}), FOV ${fmtNum(par.fov_deg)}°`;
  $("placement-impostors").textContent = `${fmtNum(t.images)} LDI images (${fmtNum(t.images_baked)} baked, ${par.construction_images} construction images, ${par.resolution} px), ${par.technique}`;
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

