#!/bin/bash
# Builds .gpu/ (ignored by git; name it in the device tool's `carry`) for a run of gpu_suite.py on a GPU
# machine without the validation install or a network (experiments/README.md, "On a machine without the
# validation install"): Pinocchio and coal (cmeel wheels for Python 3.12, stripped to the libraries their
# extensions load), pytorch-kinematics, trimesh; example-robot-data's Panda (collision meshes), Baxter and
# Talos files; MotionBenchMaker's problems; a clean copy of HEAD (helpers' uncommitted edits stay behind).
# Optional: PyRoki and jaxls sources (PYROKI_SRC, JAXLS_SRC: checkouts; their pure-Python dependencies are
# fetched as wheels; viser, which PyRoki imports, is not).
#
#   bash experiments/gpu_carry.sh              # then, on the device: bash .gpu/run.sh [gpu_suite.py options]
set -euo pipefail
ROOT=$(git rev-parse --show-toplevel)
G=$ROOT/.gpu
grep -qx '/.gpu/' "$ROOT/.git/info/exclude" 2>/dev/null || echo '/.gpu/' >>"$ROOT/.git/info/exclude"
rm -rf "$G" && mkdir -p "$G"
W=$(mktemp -d) && S=$W/gpusite
P="--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64"
P="$P --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64"
python -m pip download -q $P -d "$W/whl" pin==4.1.0 coal==3.0.3
python -m pip download -q --no-deps $P -d "$W/whl" pytorch-kinematics==0.10.0 arm-pytorch-utilities==0.5.0 \
    pytorch-seed==0.2.0 trimesh==5.2.0 pycollada tyro jaxlie jax_dataclasses loguru yourdfpy termcolor \
    docstring-parser typeguard shtab
rm -f "$W"/whl/numpy-*.whl  # the machine's own
python -m pip install -q --no-deps --no-compile --target "$S" $P --platform any "$W"/whl/*.whl
# keep the shared libraries the Python extensions load (and theirs), nothing else of the C++ install
(cd "$S/cmeel.prefix" && rm -rf include bin share lib/cmake lib/pkgconfig && find . -name '*.a' -delete && python - <<'EOF'
import glob, os, subprocess
libs = {f: os.path.join(d, f) for d in ("lib", "lib64") if os.path.isdir(d) for f in os.listdir(d) if ".so" in f}
todo, keep = glob.glob("lib/python3.12/site-packages/**/*.so*", recursive=True), set()
while todo:
    out = subprocess.run(["readelf", "-d", todo.pop()], capture_output=True, text=True).stdout
    for name in (line.split("[")[1].split("]")[0] for line in out.splitlines() if "(NEEDED)" in line):
        if name in libs and libs[name] not in keep:
            keep.add(libs[name])
            todo.append(libs[name])
for path in set(libs.values()) - keep:
    os.remove(path)
EOF
find . -name '*.so*' -exec strip --strip-unneeded {} \;)
for src in "${PYROKI_SRC:-}" "${JAXLS_SRC:-}"; do
    [ -n "$src" ] && cp -r "$src"/src/* "$S"/
done
find "$S" -name __pycache__ -prune -exec rm -rf {} +
tar -cJf "$G/site.tar.xz" -C "$W" gpusite
# data: example-robot-data's files the suite reads (the URDFs name their meshes by this folder's path)
R=$(cd "$ROOT/experiments" && python -c "import _bench; print(_bench.example_robot_data())")
D=$G/erd/example-robot-data/robots
mkdir -p "$D/panda_description/meshes" "$D/baxter_description" "$D/talos_data" "$G/mbm"
cp -r "$R/panda_description/urdf" "$R/panda_description/srdf" "$R/panda_description/LICENSE" "$D/panda_description/"
cp -r "$R/panda_description/meshes/collision" "$D/panda_description/meshes/"
cp -r "$R/baxter_description/urdf" "$D/baxter_description/"
cp -r "$R/talos_data/robots" "$R/talos_data/srdf" "$D/talos_data/"
cp "$ROOT/../shared/data/mbm/panda_mbm_problems.json" "$G/mbm/"
mkdir -p "$G/tree" && git -C "$ROOT" archive HEAD | tar -x -C "$G/tree"
cat >"$G/run.sh" <<'EOF'
#!/bin/bash
# on the device: unpack the wheels, run gpu_suite.py from the clean copy, results and log into $OUT
G=$PWD/.gpu
tar -xJf "$G/site.tar.xz" -C /tmp || exit 1
S=/tmp/gpusite
export PYTHONPATH=$S:$S/cmeel.prefix/lib/python3.12/site-packages:$G/tree
export LD_LIBRARY_PATH=$S/cmeel.prefix/lib:$S/cmeel.prefix/lib64:${LD_LIBRARY_PATH:-}
export EXAMPLE_ROBOT_DATA=$G/erd/example-robot-data/robots PYTHONUNBUFFERED=1 XLA_PYTHON_CLIENT_PREALLOCATE=false
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c "import jax, torch; print('jax', jax.__version__, jax.devices(), 'torch', torch.__version__)"
cd "$G/tree" && cp experiments/results/nvidia-h200.md "$OUT/" 2>/dev/null
timeout "${SUITE_TIMEOUT:-540}" python3 experiments/gpu_suite.py --mbm "$G/mbm/panda_mbm_problems.json" \
    --out "$OUT/nvidia-h200.md" "$@" 2>&1 | tee "$OUT/log.txt"
EOF
rm -rf "$W"
du -sh "$G"
