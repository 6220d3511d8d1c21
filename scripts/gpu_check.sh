#!/usr/bin/env bash
# Issue 15's measurement on a GPU machine: CUDA tests, `harness bench train` of MEDAL for E = 1, 8, 32, 128 members on
# sawyer_door and tabletop (per-member and aggregate steps/s, time split), and the packing of Table 1 for this node.
#
# On a machine with internet (pip, CUDA build of torch):   pip install torch --index-url \
#     https://download.pytorch.org/whl/cu126 && pip install -e '.[test]' && bash scripts/gpu_check.sh
# On the workplace's device machine (no internet; a CUDA PyTorch image): first, here, `bash scripts/gpu_prepare.sh`,
# then run(command="bash scripts/gpu_check.sh", carry=[".whl", ".earl"], timeout_s=540).
# Everything goes to $OUT (or ./gpu_check_out): gpu_check.log and bench.csv, written as it goes (a run cut short by
# its time limit still returns what it measured).
set -uo pipefail
cd "$(dirname "$0")/.."
out=${OUT:-gpu_check_out}
mkdir -p "$out"
exec > >(tee "$out/gpu_check.log") 2>&1
t0=$(date +%s)
stamp() { echo "== $(( $(date +%s) - t0 ))s: $*"; }

if [ -d .whl ]; then  # the device machine: install the carried wheels beside the image's packages
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl \
    || { echo "gpu_check: could not install .whl/"; exit 1; }
  export PYTHONPATH="/tmp/site:$PWD${PYTHONPATH:+:$PYTHONPATH}"
fi
[ -d .earl ] && export HARNESS_DATA_DIR="$PWD/.earl"
cores=$(python3 -c "import os; print(len(os.sched_getaffinity(0)))")  # (nproc follows OMP_NUM_THREADS)
export MUJOCO_GL=egl OMP_NUM_THREADS=1 PYTHONUNBUFFERED=1
H="python3 -m harness.cli"
device=${DEVICE:-cuda}  # DEVICE=cpu MEMBERS="1 2" tries the script on a CPU machine
members=${MEMBERS:-1 8 32 128}

stamp "machine"
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
echo "$cores cores"
python3 -c "import torch; print('torch', torch.__version__, 'cuda', torch.version.cuda,
                              torch.cuda.get_device_name() if torch.cuda.is_available() else 'no GPU')"
[ "$device" = cpu ] || python3 -c "import torch; assert torch.cuda.is_available()" \
  || { echo "gpu_check: torch sees no CUDA device"; exit 1; }

stamp "CUDA tests, the compiled static update on CUDA (CUDA graphs), the one-read-per-step test"
python3 -m pytest -q -p no:cacheprovider -m "slow or not slow" tests/test_cuda.py tests/test_static_update.py \
  tests/test_device_step.py \
  --deselect "tests/test_static_update.py::test_compiled_static_update_equals_the_uncompiled_one[cpu]" 2>&1 | tail -15

stamp "bench train: MEDAL, device=$device"
echo "env,members,env_workers,update,per_member,aggregate,split" > "$out/bench.csv"
bench() {  # env members update
  local workers=0
  [ "$2" -ge 32 ] && workers=$(( cores > 4 ? cores - 2 : 0 ))
  local line
  line=$(timeout 200 $H bench train algo=medal env=$1 device=$device members=$2 steps=200 repeats=2 seed_steps=100 \
         env_workers=$workers update=$3 2>&1) || echo "bench $1 E=$2 update=$3 failed or timed out"
  echo "$line" | tail -4
  local rates split
  rates=$(echo "$line" | sed -n 's/.*per member: \([0-9.,]*\) *aggregate: \([0-9.,]*\).*/\1|\2/p' | tr -d , | tr '|' ,)
  split=$(echo "$line" | sed -n 's/.*time split: //p')
  echo "$1,$2,$workers,$3,${rates:-,},\"$split\"" >> "$out/bench.csv"
}
for env in sawyer_door tabletop_manipulation; do
  for E in $members; do bench $env "$E" default; done
done
stamp "bench train: the compiled static update (torch.compile, CUDA graphs)"
for E in $members; do
  [ "$E" -ge 8 ] && bench sawyer_door "$E" compiled
done
cat "$out/bench.csv"

stamp "Table 1 packed for this node"
$H run suite=earl_sparse device=$device calibrate=false --dry-run 2>&1 | head -4
stamp "done"
