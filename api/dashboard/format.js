// The dashboard's text of numbers, sizes, durations, times and counts, and the parsing of a
// typed vector.

export function fmtNum(x, digits = 3) {
  if (x === null || x === undefined) return "—";
  if (typeof x !== "number") return String(x);
  if (Number.isInteger(x)) return x.toLocaleString("en-US");
  return Number(x.toPrecision(digits)).toString();
}

export function fmtVec(v) { return "(" + v.map((x) => fmtNum(x, 4)).join(", ") + ")"; }

export function fmtBytes(n) {
  if (n === null || n === undefined) return "—";
  const units = ["B", "KiB", "MiB", "GiB"];
  let i = 0;
  while (n >= 1024 && i < units.length - 1) { n /= 1024; i++; }
  return (i ? n.toFixed(1) : n) + " " + units[i];
}

export function fmtSeconds(s) {
  if (s === null || s === undefined) return "—";
  if (s < 60) return s.toFixed(s < 10 ? 2 : 0) + " s";
  const m = Math.floor(s / 60);
  if (m < 60) return `${m} min ${Math.round(s - 60 * m)} s`;
  return `${Math.floor(m / 60)} h ${m % 60} min`;
}

export function fmtTime(epoch) {
  if (!epoch) return "—";
  return new Date(epoch * 1000).toLocaleString();
}

export function pct(p) { return (100 * Math.max(0, Math.min(1, p || 0))).toFixed(0) + "%"; }

export function shortId(id) { return id ? id.slice(0, 8) : ""; }

// A job while a worker checks its cells' full plans (state "admitting"): what its record's
// "admission" says (the progress bar stays the cells', 0 until they are baked).
export function admitting(job) {
  const a = job.state === "admitting" ? job.admission : null;
  if (!a) return null;
  const text = `admitting: ${a.done.toLocaleString("en")} of ${a.total.toLocaleString("en")} cells checked` +
    (a.failed ? `, ${a.failed.toLocaleString("en")} failed` : "");
  return {text};
}

export function countsText(counts, total) {
  const parts = [`${counts.done}/${total} done`];
  for (const name of ["running", "queued", "failed", "cancelled"]) if (counts[name]) parts.push(`${counts[name]} ${name}`);
  return parts.join(", ");
}

export function parseVec(text, name, integer = false) {
  const parts = String(text || "").split(/[\s,;]+/).filter((s) => s !== "");
  const values = parts.map(Number);
  if (values.length !== 3 || values.some((v) => !Number.isFinite(v))) {
    throw new Error(`${name}: give three numbers "x, y, z", got "${text}"`);
  }
  if (integer && values.some((v) => !Number.isInteger(v))) throw new Error(`${name}: give three whole numbers, got "${text}"`);
  return values;
}
