// The render workers of the home view (GET /v1/workers, polled): host, kind (CPU/GPU) and GL
// renderer, the cells each runs now, and its last heartbeat; a worker whose heartbeat is older than
// the lease is shown as lost (its cells go to other workers when their leases run out).

import {api, apiKey} from "./api.js";
import {$, el} from "./dom.js";
import {fmtSeconds, pct, shortId} from "./format.js";

export async function refreshWorkers() {
  if (!apiKey()) return;
  const {workers, lease_s: lease} = await api("/v1/workers");
  const rows = workers.map((w) => {
    const cells = w.cells.map((c) =>
      el("a", {href: `#/jobs/${c.job_id}`, "data-testid": "worker-cell", text: `${shortId(c.job_id)} #${c.index} (${pct(c.progress)})`}));
    if (w.other_cells) cells.push(el("span", {class: "muted", text: `${w.other_cells} of other tenants`}));
    return el("tr", {"data-testid": "worker-row", "data-worker": w.name, "data-alive": String(w.alive)},
      el("td", {}, el("code", {text: w.name})),
      el("td", {text: w.host}),
      el("td", {"data-testid": "worker-kind", text: w.kind.toUpperCase(), title: w.renderer || "renderer not known yet"}),
      el("td", {class: "small", "data-testid": "worker-renderer", text: w.renderer || "not known yet"}),
      el("td", {"data-testid": "worker-cells"}, ...(cells.length ? cells : [el("span", {class: "muted", text: "idle"})])),
      el("td", {"data-testid": "worker-heartbeat", class: w.alive ? "" : "err",
        text: `${fmtSeconds(w.heartbeat_age_s)} ago` + (w.alive ? "" : ` (lost: over the ${lease} s lease)`)}));
  });
  $("workers-body").replaceChildren(...rows);
  $("workers-empty").hidden = workers.length > 0;
}
