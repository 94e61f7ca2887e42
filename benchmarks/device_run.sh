#!/usr/bin/env bash
# The NVIDIA run of the benchmarks (issue 29 item 5), as it ran on a lent H200 through this
# workplace's device tool: one call, steps in order of value, each with its own time limit, logs
# under $OUT.  The machine is bare and offline, so this checkout carries what its image lacks:
#   .gl/             the glvnd/EGL/Vulkan loader .debs (the device README's recipe)
#   .whl/            cp312 wheels of moderngl, glcontext, trimesh, SQLAlchemy, greenlet
#   .shared_scenes/  a copy of ../shared/scenes (for the tests that load the third-party scenes)
# The image's python3 (3.12, with numpy, scipy, numba, scikit-image, matplotlib, pytest) runs
# this checkout through a shim folder that names it `farfield`.
# Usage there: bash benchmarks/device_run.sh [STEP ...]   (default: every step)
set -u
OUT="${OUT:-/tmp/farfield-device-out}"
mkdir -p "$OUT"
for f in .gl/*.deb; do dpkg -x "$f" /; done
ldconfig
vendor=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json
if [ -f "$vendor" ]; then export __EGL_VENDOR_LIBRARY_FILENAMES="$vendor"; fi
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
mkdir -p /tmp/shim && ln -sfn "$PWD" /tmp/shim/farfield
if [ -d .shared_scenes ] && [ ! -e ../shared/scenes ]; then mkdir -p ../shared && ln -sfn "$PWD/.shared_scenes" ../shared/scenes; fi
export PYTHONPATH="/tmp/shim:/tmp/site:$PWD" PYTHONUNBUFFERED=1

step() {  # step NAME SECONDS COMMAND...: run with a limit, log to $OUT/NAME.log, print its tail
    local name=$1 limit=$2 start=$SECONDS rc
    shift 2
    echo "== $name (limit ${limit} s)"
    timeout "$limit" "$@" >"$OUT/$name.log" 2>&1
    rc=$?
    echo "   rc $rc after $((SECONDS - start)) s"
    tail -n "${TAIL:-25}" "$OUT/$name.log"
}

want() { [ $# -eq 0 ] || [[ " $* " == *" $name "* ]]; }
steps=("$@")
nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm,clocks.mem --format=csv 2>&1
python3 -c 'import numpy, numba, scipy, moderngl, trimesh; print("numpy", numpy.__version__, "numba", numba.__version__, "scipy", scipy.__version__, "moderngl", moderngl.__version__, "trimesh", trimesh.__version__)'
name=egl; if want "${steps[@]}"; then
    step egl 90 python3 -m pytest -q -p no:cacheprovider -rA tests/test_context.py
fi
name=layered; if want "${steps[@]}"; then
    step layered 120 python3 benchmarks/bench_layered.py --only speed
fi
name=envmap; if want "${steps[@]}"; then
    TAIL=45 step envmap 240 python3 benchmarks/bench_envmap.py --before '' --out "$OUT/envmap"
fi
name=tests; if want "${steps[@]}"; then
    step tests 150 python3 -m pytest -q -p no:cacheprovider -n 8 -rfE \
        tests/test_recording.py tests/test_bake.py tests/test_evaluation.py tests/test_culling.py tests/test_envmap.py \
        tests/test_tdm.py tests/test_tdm_texture.py tests/test_ldi_warp.py tests/test_point_appearance.py \
        tests/test_layer_figures.py tests/test_bundle_render.py tests/test_placement_runtime.py tests/test_colour.py
fi
nvidia-smi --query-gpu=clocks.sm,clocks.mem,temperature.gpu --format=csv 2>&1
