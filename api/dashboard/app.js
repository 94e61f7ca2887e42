// farfield dashboard: plain JavaScript ES modules, no build step, no external resources.  This
// entry module routes between the home view and a job's page, polls, and wires the page's
// controls; every API call goes through api.js, which sends the key (localStorage) as
// "Authorization: Bearer <key>".

import {apiKey, onKeyRejected} from "./api.js";
import {FINAL, state} from "./state.js";
import {$, showBox, showGlobalError} from "./dom.js";
import {applyKey, refreshHealth} from "./key.js";
import {onUpload, refreshScenes, showSceneInfo} from "./scenes.js";
import {onAlgorithmChange, onModeChange, onSubmitJob, onTechniqueChange, refreshTechniques} from "./job-form.js";
import {refreshJobs} from "./jobs.js";
import {refreshWorkers} from "./workers.js";
import {jobAction, refreshJob, renderCellPanel, renderMap, saveFile} from "./job.js";
import {renderPlacement} from "./placement.js";

const POLL_MS = 1000;

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
  if (!apiKey() || (document.hidden && !force)) return; // no polling from a background tab
  if (state.polling) {
    if (force) setTimeout(() => tick(true), 100); // a navigation must not be lost behind a poll
    return;
  }
  state.polling = true;
  try {
    if (state.view === "home") {
      await refreshJobs();
      await refreshWorkers();
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
  onKeyRejected((error) => showGlobalError(`API key rejected: ${error.message}`));
  $("api-key").value = apiKey();
  $("key-needed").hidden = !!apiKey();
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
  $("job-download").addEventListener("click", () => saveFile(`/v1/jobs/${state.jobId}/database.zip`, `job-${state.jobId}.zip`));
  for (const button of document.querySelectorAll("#cell-panel [data-download]")) {
    button.addEventListener("click", () => {
      const name = button.dataset.download;
      const ext = name.split(".").pop();
      saveFile(`/v1/jobs/${state.jobId}/cells/${state.selected}/${name}`, `cell-${String(state.selected).padStart(5, "0")}.${ext}`);
    });
  }
  window.addEventListener("hashchange", route);
  refreshHealth();
  setInterval(refreshHealth, 10000);
  if (apiKey()) {
    refreshScenes().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
    refreshTechniques().catch((error) => { if (error.status !== 401) showGlobalError(error.message); });
  }
  route();
  setInterval(() => tick(false), POLL_MS);
}

start();
