#!/usr/bin/env bash
# Issue 57's "done when" measured as a user runs it: `farfield up`, `farfield submit --placement
# ... --visibility --wait --download`, `farfield walkthrough DB SCENE --random N --json`.
#
# Usage: benchmarks/service_placement_walk.sh [SCENE ...]   (street, downtown, city, dense; default street)
#   env: VIEWS (100), SEED (0), RESOLUTION (128), CPV_DIVISIONS (8), VDI_DEG (11.25), SIDES (both: the
#        materials double-sided as the built scene's objects; one: one-sided), KEEP (a folder to keep),
#        ALSO (another source of candidates for the job's --also, e.g. lod: simplified geometry competes),
#        CALIBRATE (a quantile, e.g. 0.9: the job's cost model is `farfield calibrate GLB --view-space ... --quantile Q
#        --seed 1` on the scene's own frames, not the builtin llvmpipe model; t_max stays the builtin's reference budget)
#
# Per scene: the benchmark scene written as a GLB with its view space and t_max (half the worst
# view's estimate by the builtin llvmpipe model: benchmarks/write_benchmark_scene.py); a fresh
# `farfield up` (embedded Redis, API, one llvmpipe worker, its own FARFIELD_HOME); the placement job
# (layered, 45° fov, CPV side / CPV_DIVISIONS, VDI_DEG intervals, --visibility, no per-cell
# evaluation); the database downloaded and walked with the PVS. Prints the commands, then one table
# (benchmarks/service_placement_table.py): impostors, memory, CPVs and unsolved from the job's
# placement record, the job's time breakdown, the walk's hole and PVS-dropped pixels, the share
# within t_max (measured and by the estimate), estimate ÷ measured p50 / p95. No timing asserts.
set -euo pipefail
cd "$(dirname "$0")/.."
PY=.venv/bin/python
FF=.venv/bin/farfield
VIEWS=${VIEWS:-100} SEED=${SEED:-0} RESOLUTION=${RESOLUTION:-128} CPV_DIVISIONS=${CPV_DIVISIONS:-8} VDI_DEG=${VDI_DEG:-11.25} SIDES=${SIDES:-both} ALSO=${ALSO:-} CALIBRATE=${CALIBRATE:-}
WORK=${KEEP:-$(mktemp -d -t farfield-svc-walk-XXXX)}
mkdir -p "$WORK"
SCENES=("${@:-street}")
export FARFIELD_ADMIN_KEY=ff_walk_0123456789abcdef FARFIELD_API_KEY=ff_walk_0123456789abcdef
UP=
stop() { if [ -n "$UP" ]; then kill -INT "$UP" 2>/dev/null || true; wait "$UP" 2>/dev/null || true; UP=; fi; }
trap stop EXIT
run() { echo "\$ farfield $*" >&2; "$FF" "$@"; }

for NAME in "${SCENES[@]}"; do
  OUT=$WORK/$NAME
  mkdir -p "$OUT"
  eval "$($PY benchmarks/write_benchmark_scene.py "$NAME" "$OUT/$NAME.glb" --resolution "$RESOLUTION" --cpv-divisions "$CPV_DIVISIONS" --sides "$SIDES")"
  echo "# $NAME ($SIDES-sided): $OBJECTS objects, $TRIANGLES triangles; view space $VIEW_SPACE; t_max $T_MAX_MS ms (worst view $WORST_MS); CPV $CPV_SIZE" >&2
  MODEL=llvmpipe
  if [ -n "$CALIBRATE" ]; then
    run calibrate "$GLB" --view-space="$VIEW_SPACE" --resolution "$RESOLUTION" --fov 45 --quantile "$CALIBRATE" --seed 1 \
      --out "$OUT/model.json" >"$OUT/calibrate.txt"
    MODEL=$OUT/model.json
  fi
  PORT=$($PY -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
  export FARFIELD_HOME=$OUT/home FARFIELD_URL=http://127.0.0.1:$PORT
  echo "\$ FARFIELD_HOME=$FARFIELD_HOME farfield up --workers 1 --port $PORT &" >&2
  "$FF" up --workers 1 --port "$PORT" >"$OUT/up.log" 2>&1 &
  UP=$!
  for _ in $(seq 240); do
    curl -sf "$FARFIELD_URL/v1/health" >/dev/null 2>&1 && break
    kill -0 "$UP" 2>/dev/null || { cat "$OUT/up.log" >&2; exit 1; }
    sleep 0.5
  done
  rm -rf "$OUT/db"
  run submit "$GLB" --placement --view-space="$VIEW_SPACE" --frame-ms "$T_MAX_MS" --cost-model "$MODEL" \
    --resolution "$RESOLUTION" --fov 45 --cpv-size "$CPV_SIZE" --vdi-deg "$VDI_DEG" --visibility --no-evaluate \
    ${ALSO:+--also "$ALSO"} --wait --download "$OUT/db" --json >"$OUT/job.json"
  JOB=$($PY -c 'import json, sys; print(json.load(open(sys.argv[1]))["id"])' "$OUT/job.json")
  curl -sf -H "Authorization: Bearer $FARFIELD_API_KEY" "$FARFIELD_URL/v1/jobs/$JOB/placement" >"$OUT/placement.json"
  curl -sf -H "Authorization: Bearer $FARFIELD_API_KEY" "$FARFIELD_URL/v1/jobs/$JOB" >"$OUT/record.json"
  stop
  run walkthrough "$OUT/db" "$GLB" --random "$VIEWS" --seed "$SEED" --json >"$OUT/walk.json"
done
$PY benchmarks/service_placement_table.py "$WORK" "${SCENES[@]}"
