#!/usr/bin/env bash
# The checks of the CUDA paths, in one run on a machine with an NVIDIA GPU.
#
#   bash scripts/gpu_check.sh OUT_DIR
#
# 1. the tests of the CUDA paths (`-k "cuda or gpu"`: the `gpu`-marked tests and the
#    `device`-fixture tests' cuda cases), which are skipped on machines without CUDA;
# 2. scripts/bench_gpu.py (each CUDA path against the CPU in the same run) -> OUT_DIR/gpu.json;
# 3. the main job with the planner on CUDA (`iplanner-experiment device=cuda`), from nothing;
# 4. the default test run, as a check of the project on that machine's Python and torch.
#
# Each stage has a time limit of its own, all of them GPU_CHECK_S seconds (default 540)
# together, and writes its log under OUT_DIR; a failed stage does not stop the later ones.
# The project's dependencies must be importable: where the machine cannot install from a
# package index, put their wheels (for its Python) in .whl/ and they are installed into
# /tmp/site first.
set -u
usage="usage: bash scripts/gpu_check.sh OUT_DIR  (the CUDA tests, bench_gpu.py, the main job on CUDA and the default test run; logs under OUT_DIR)"
case "${1:-}" in
  -h|--help) echo "$usage"; exit 0 ;;
  -*|"") echo "$usage" >&2; exit 2 ;;
esac
out=$1
mkdir -p "$out"
: > "$out/stages.txt"  # this run's stages only
job=$(mktemp -d /tmp/main_job.XXXXXX)  # a fresh, empty run folder (one with results is refused)
export PYTHONUNBUFFERED=1
if compgen -G ".whl/*.whl" > /dev/null; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
deadline=${GPU_CHECK_S:-540}  # seconds for all stages together
stage() {  # stage NAME SECONDS COMMAND...: run with a limit, log to OUT_DIR/NAME.log
  local name=$1 limit=$2
  shift 2
  ((limit > deadline - SECONDS)) && limit=$((deadline - SECONDS))
  if ((limit < 10)); then
    echo "stage $name: skipped, out of time" | tee -a "$out/stages.txt"
    return
  fi
  local t0=$SECONDS
  timeout "$limit" "$@" > "$out/$name.log" 2>&1
  local rc=$?
  echo "stage $name: exit $rc in $((SECONDS - t0)) s" | tee -a "$out/stages.txt"
  tail -n 25 "$out/$name.log"
}
{
  nvidia-smi --query-gpu=name,driver_version,memory.total,clocks.sm --format=csv
  nproc
  python3 -c "import sys, torch, mujoco, gpytorch, lightning; print(sys.version.split()[0], \
torch.__version__, torch.cuda.get_device_name(0), mujoco.__version__, gpytorch.__version__, \
lightning.__version__)"
} > "$out/env.txt" 2>&1
cat "$out/env.txt"
stage tests_cuda 240 python3 -m pytest -q -p no:cacheprovider -n 8 -k "cuda or gpu" -m "not slow"
stage bench_gpu 300 python3 scripts/bench_gpu.py --json "$out/gpu.json" --force
stage main_job 240 python3 -m iplanner_torch.cli.experiment device=cuda progress=false \
  "hydra.run.dir=$job"
cp "$job"/*.csv "$out/" 2>/dev/null
# one torch thread per worker (14 workers of 16 threads each were oversubscribed); -v names
# each test as it ends, so that a failure is known even when the stage runs out of time
OMP_NUM_THREADS=1 stage tests_all 600 python3 -m pytest -v -p no:cacheprovider -n 14 -m "not slow"
grep -E "FAILED|ERROR" "$out/tests_all.log" > "$out/tests_all_failed.txt" || true
