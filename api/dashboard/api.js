// The API client of the dashboard's pages (index.html's modules and viewer.html's viewer.js): the
// API key, kept in localStorage and sent as "Authorization: Bearer <key>" on every call, and the
// request helpers.  No build step: an ES module served as is (api/routes_dashboard.py).

export const KEY_STORAGE = "farfield.apiKey";

// The key in use: what localStorage holds now (one place, so every page and tab agrees).
export function apiKey() {
  return localStorage.getItem(KEY_STORAGE) || "";
}

// Store a key (trimmed; empty: forget it); returns the key now in use.
export function setApiKey(key) {
  const trimmed = String(key || "").trim();
  if (trimmed) localStorage.setItem(KEY_STORAGE, trimmed);
  else localStorage.removeItem(KEY_STORAGE);
  return trimmed;
}

let keyRejected = null; // (ApiError) => void, told when the key in use is refused (401)

// What a page does when the service refuses the key in use (the dashboard shows it at the top).
export function onKeyRejected(handler) {
  keyRejected = handler;
}

// An answer that is not 2xx: its HTTP status (0: the service could not be reached), the message,
// the service's error type ("error" of the body) and the parsed body (null when not JSON).
export class ApiError extends Error {
  constructor(status, message, kind, body = null, statusText = "") {
    super(message);
    this.status = status;
    this.kind = kind;
    this.body = body;
    this.statusText = statusText;
  }
}

export function errorMessage(status, body) {
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

// One call: the parsed JSON (null for 204), or with raw the Response, with binary an ArrayBuffer.
// json: a body sent as JSON; form: a FormData.  Throws ApiError.
export async function api(path, {method = "GET", json, form, raw = false, binary = false} = {}) {
  const headers = {};
  const key = apiKey();
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
    const error = new ApiError(response.status, errorMessage(response.status, parsed), parsed && parsed.error, parsed, response.statusText);
    // (An answer to a key changed meanwhile says nothing about the key in use now.)
    if (response.status === 401 && key === apiKey() && keyRejected) keyRejected(error);
    throw error;
  }
  if (raw) return response;
  if (binary) return response.arrayBuffer();
  if (response.status === 204) return null;
  return response.json();
}

// A page of a paged listing (GET /v1/scenes, /v1/jobs, a scene's objects): the body is a JSON
// array of the page, X-Total-Count the entries in all pages.
export async function apiPage(path) {
  const response = await api(path, {raw: true});
  const items = await response.json();
  const total = Number(response.headers.get("X-Total-Count") ?? items.length);
  return {items, total};
}

// The techniques (GET /v1/techniques): name -> {name, scope, help, image, options}.  What the
// pages know of a technique comes from here, never from its name.
export async function fetchTechniques() {
  const body = await api("/v1/techniques");
  return new Map(body.techniques.map((t) => [t.name, t]));
}

// The placement algorithms (GET /v1/placement-algorithms): {default, algorithms: name -> {name, help,
// technique, index_kind, noun, choice, summary, images, labels, fields}}.  What the pages know of an
// algorithm comes from here, never from its name.
export async function fetchPlacementAlgorithms() {
  const body = await api("/v1/placement-algorithms");
  return {default: body.default, algorithms: new Map(body.algorithms.map((a) => [a.name, a]))};
}

// A file the API serves, saved by the browser as ``filename``.  Throws ApiError.
export async function download(path, filename) {
  const response = await api(path, {raw: true});
  const url = URL.createObjectURL(await response.blob());
  const a = document.createElement("a");
  a.href = url;
  a.download = filename;
  document.body.appendChild(a);
  a.click();
  a.remove();
  setTimeout(() => URL.revokeObjectURL(url), 10000);
}
