// The job list of the home view (GET /v1/jobs, polled).

import {apiKey, apiPage} from "./api.js";
import {state, techniqueHelp} from "./state.js";
import {$, el, setBar, setState, showMore} from "./dom.js";
import {admitting, countsText, fmtSeconds, fmtTime, pct, shortId} from "./format.js";

export async function refreshJobs() {
  if (!apiKey()) return;
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
    const checking = admitting(job);
    setBar(progressCell.querySelector(".fill"), job);
    progressCell.querySelector(".bar-label").textContent = checking ? checking.text
      : pct(job.progress) + (job.eta_s != null ? `, ETA ${fmtSeconds(job.eta_s)}` : "");
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

