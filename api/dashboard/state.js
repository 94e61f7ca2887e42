// The dashboard's state, shared by its modules: what the page shows and what it has fetched.

export const FINAL = new Set(["done", "failed", "cancelled"]); // job states that no longer change
export const PLACEMENT = "placement"; // the job type of a placement job

export const state = {
  view: "home",
  jobId: null,
  job: null,
  jobFetchedAt: 0,
  jobCellsAt: 0, // when the job's cells were last fetched (job.js: a large job is polled without them)
  scenes: new Map(), // id -> scene record (a summary: its objects are GET objects_url, paged)
  sceneObjects: new Map(), // id -> the names of its first objects, for the job form
  map: null, // {key, rects: Map(index -> {rect, title, bar, w})}
  level: 0, // y level shown on the map (grid jobs)
  selected: null, // selected cell index
  atlas: {key: null, url: null}, // what the thumbnail shows
  polling: false,
  techniques: new Map(), // name -> GET /v1/techniques entry
  algorithms: new Map(), // name -> GET /v1/placement-algorithms entry
  defaultAlgorithm: null, // the algorithm of a placement that names none
  optionFields: new Map(), // technique name -> its option fields (kept across switches)
  placement: {key: null, doc: null, error: null}, // a placement job's GET /v1/jobs/{id}/placement, fetched once per end
  region: null, // the footprint key of the region selected on the placement map
  colour: "after", // the placement map's colour: estimated time "before" or "after" placement
};

// What GET /v1/techniques says of a technique (null: not listed, or not fetched yet).
export function techniqueScope(name) {
  const t = state.techniques.get(name);
  return t ? t.scope : null;
}

export function techniqueHelp(name) {
  const t = state.techniques.get(name);
  return t ? t.help : "";
}

// What GET /v1/placement-algorithms says of a placement's algorithm (its name; null or absent: the
// default); null: not listed, or not fetched yet.
export function placementAlgorithm(name) {
  return state.algorithms.get(name || state.defaultAlgorithm) || null;
}

// The techniques that make impostors of one part (scope "part"), by name.
export function partTechniques() {
  return [...state.techniques.values()].filter((t) => t.scope === "part").map((t) => t.name);
}
