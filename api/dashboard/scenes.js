// Scenes: the list, upload and delete; the job form's scene choice and its summary.

import {api, apiKey, apiPage} from "./api.js";
import {state} from "./state.js";
import {$, el, showBox, showMore} from "./dom.js";
import {fmtBytes, fmtNum, fmtVec, shortId} from "./format.js";

export async function refreshScenes() {
  if (!apiKey()) return;
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

// The grid's (or view space's) corners follow the chosen scene's bounds until the user edits them:
// a fixed default suited one scene's scale and not another's (a 1,200-unit park was offered a
// 0.2-unit grid).
function suggestBox(lo, hi) {
  for (const [id, corner] of [["job-lo", lo], ["job-hi", hi]]) {
    const input = $(id);
    const text = corner.map((x) => String(Number(Number(x).toPrecision(6)))).join(", ");
    input.placeholder = text;
    if (!input.value || input.value === input.dataset.suggested) input.value = text;
    input.dataset.suggested = text;
  }
}

export function showSceneInfo() {
  const scene = state.scenes.get($("job-scene").value);
  const info = $("job-scene-info");
  if (!scene) { info.textContent = ""; return; }
  const [lo, hi] = scene.bounds;
  suggestBox(lo, hi);
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

export async function onUpload(event) {
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
    input.value = "";
    try { // the result shows once the job form has the new scene chosen (a test, or a quick user, read it at once)
      await refreshScenes();
      $("job-scene").value = scene.id;
      showSceneInfo();
    } finally {
      result.hidden = false;
    }
  } catch (error) {
    showBox($("upload-error"), (error.kind ? `${error.kind}: ` : "") + error.message);
  } finally {
    $("upload-busy").hidden = true;
  }
}

