// The API key form and the service's health (GET /v1/health, no key needed).

import {setApiKey} from "./api.js";
import {$, showGlobalError} from "./dom.js";

export function applyKey(key) {
  const stored = setApiKey(key);
  $("api-key").value = stored;
  $("key-needed").hidden = !!stored;
  showGlobalError("");
}

export async function refreshHealth() {
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

