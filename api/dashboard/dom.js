// The dashboard's DOM helpers: elements and SVG nodes built from attributes, message boxes,
// state badges and progress bars.

import {FINAL} from "./state.js";
import {fmtNum, pct} from "./format.js";

const SVG_NS = "http://www.w3.org/2000/svg";

export const $ = (id) => document.getElementById(id);

export function el(tag, attrs = {}, ...children) {
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

export function svg(tag, attrs = {}) {
  const node = document.createElementNS(SVG_NS, tag);
  for (const [name, value] of Object.entries(attrs)) node.setAttribute(name, value);
  return node;
}

export function showBox(node, message) {
  node.textContent = message || "";
  node.hidden = !message;
}

export function showGlobalError(message) { showBox($("global-error"), message); }

export function setState(node, value) {
  node.textContent = value;
  node.className = "state " + value;
  node.dataset.state = value;
}

export function setBar(fill, job) {
  fill.style.width = pct(job.progress);
  fill.className = "fill " + (FINAL.has(job.state) ? job.state : "");
  fill.dataset.progress = String(job.progress);
  fill.dataset.state = job.state;
}

export function showMore(node, shown, total, what) {
  node.hidden = total <= shown;
  node.textContent = `the newest ${fmtNum(shown)} of ${fmtNum(total)} ${what} are listed`;
}
