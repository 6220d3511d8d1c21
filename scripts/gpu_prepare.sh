#!/usr/bin/env bash
# Run on a machine with internet, in the checkout, before scripts/gpu_check.sh goes to a GPU machine that has none:
#   .whl/   wheels (CPython 3.12, manylinux x86-64) of what the project needs beyond a CUDA PyTorch image
#   .earl/  the EARL data the runs read (demos and MuJoCo assets; HARNESS_DATA_DIR points there)
# Both are git-ignored through .git/info/exclude. With the device tool: run(command="bash scripts/gpu_check.sh",
# carry=[".whl", ".earl"]).
set -euo pipefail
cd "$(dirname "$0")/.."
for d in /.whl/ /.earl/; do
  grep -qxF "$d" .git/info/exclude 2>/dev/null || echo "$d" >> .git/info/exclude
done
rm -rf .whl && mkdir -p .whl
platforms=()
for p in manylinux_2_28 manylinux_2_27 manylinux_2_17 manylinux2014 manylinux1; do platforms+=(--platform "${p}_x86_64"); done
# pinned to the versions the CPU CI resolves today; the image already holds numpy, pandas, pyarrow, pyyaml, scipy,
# cloudpickle, matplotlib, pytest and hypothesis
python3 -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
  "${platforms[@]}" -d .whl \
  gymnasium==1.4.0 farama-notifications==0.0.4 mujoco==3.3.0 glfw==2.11.0 pyopengl==3.1.10 metaworld==3.1.1
# Meta-World's textures and scene meshes (34 MB of its 37) stay behind: the EARL Sawyer models are EARL's own files
# (.earl/assets), and the device tool carries 64 MiB at most
python3 - <<'PY'
import pathlib, zipfile
src = next(pathlib.Path(".whl").glob("metaworld-*.whl"))
tmp = src.with_suffix(".tmp")
with zipfile.ZipFile(src) as zin, zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zout:
    for item in zin.infolist():
        if not item.filename.startswith(("metaworld/assets/textures/", "metaworld/assets/scene/")):
            zout.writestr(item, zin.read(item.filename))
tmp.replace(src)
PY
data=$(python3 -c "from harness.data import find_data_dir; print(find_data_dir('demos'))")
rm -rf .earl && mkdir -p .earl && cp -r "$data/demos" "$data/assets" .earl/
du -sh .whl .earl
