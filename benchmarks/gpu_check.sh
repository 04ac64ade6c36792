#!/usr/bin/env bash
# The GPU check of issue 40 in one command (device time is minutes): the paper preset's step times and a
# truncated fit (bench_gpu.py), then torchrun mass sampling of 16 canyon samples, killed and resumed.
#   bash benchmarks/gpu_check.sh OUTDIR [PRESET] [BUDGET_S] [MASS_N]
# SKIP_BENCH=1 runs only part 2.
# Needs trimesh, point-cloud-utils, xatlas, fast-simplification importable (on the lent GPU machine they
# travel as wheels in .whl/ and are installed into /tmp/site first when present).
set -uo pipefail
out=${1:?OUTDIR}; preset=${2:-paper}; budget=${3:-120}; n=${4:-16}
mkdir -p "$out"
if [ -z "${NO_WHEELS:-}" ] && ls .whl/*.whl >/dev/null 2>&1; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target /tmp/site .whl/*.whl || exit 1
  export PYTHONPATH=/tmp/site:$PWD
else
  export PYTHONPATH=$PWD
fi
export PYTHONUNBUFFERED=1
py=python3
command -v nvidia-smi >/dev/null && nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv | tee "$out/gpu.txt"
$py -c "import torch; print('torch', torch.__version__, 'cuda', torch.cuda.is_available())"

if [ -z "${SKIP_BENCH:-}" ]; then
echo "== 1. bench_gpu.py, preset $preset, budget $budget s"
t0=$(date +%s)
timeout ${BENCH_TIMEOUT:-330} $py benchmarks/bench_gpu.py --input canyon --preset "$preset" --budget-s "$budget" \
  -n 8 --timed ${TIMED:-10} --out /tmp/gpubench ${BENCH_ARGS:-} 2>&1 | tail -n 40 | tee "$out/bench.log"
echo "bench_gpu: exit ${PIPESTATUS[0]} in $(( $(date +%s) - t0 )) s"
cp /tmp/gpubench/gpu.json /tmp/gpubench/projections.png "$out/" 2>/dev/null
fi

echo "== 2. torchrun mass sampling, $n samples of the shipped canyon"
run() { $py -m torch.distributed.run --nproc_per_node=1 --master_port=29517 -m sin3dm_lite.cli sample canyon -n "$n" \
        --out /tmp/mass --seed 0 ${MASS_ARGS:-} ; }
rm -rf /tmp/mass /tmp/mass_ref
t0=$(date +%s.%N)
timeout 200 $py -m torch.distributed.run --nproc_per_node=1 --master_port=29518 -m sin3dm_lite.cli sample canyon \
  -n "$n" --out /tmp/mass_ref --seed 0 ${MASS_ARGS:-} > "$out/mass_ref.log" 2>&1
rc=$?; t1=$(date +%s.%N)
echo "uninterrupted: exit $rc, $(ls -d /tmp/mass_ref/[0-9]* 2>/dev/null | wc -l) samples in $(python3 -c "print(round($t1 - $t0, 1))") s"
tail -n 5 "$out/mass_ref.log"
# killed and resumed: kill the whole launcher group once the first sample has landed
setsid bash -c "$(declare -f run); py=$py n=$n MASS_ARGS='${MASS_ARGS:-}'; run" > "$out/mass_kill.log" 2>&1 &
pid=$!
for i in $(seq 1 3000); do
  k=$(ls -d /tmp/mass/[0-9]* 2>/dev/null | wc -l); [ "$k" -ge 1 ] && break; sleep 0.05
done
kill -9 -- -$pid 2>/dev/null; pkill -9 -f -- "--out /tmp/mass --seed"; wait $pid 2>/dev/null; sleep 1
echo "killed with $(ls -d /tmp/mass/[0-9]* 2>/dev/null | wc -l) samples landed"
t0=$(date +%s.%N); timeout 200 bash -c "$(declare -f run); py=$py n=$n MASS_ARGS='${MASS_ARGS:-}'; run" > "$out/mass_resume.log" 2>&1
rc=$?; t1=$(date +%s.%N)
echo "resumed: exit $rc, $(ls -d /tmp/mass/[0-9]* | wc -l) samples in $(python3 -c "print(round($t1 - $t0, 1))") s"
grep -a "already" "$out/mass_resume.log" | tr "\r" "\n" | grep -a already | head -2; tail -n 3 "$out/mass_resume.log"
$py - <<'PY'
import pathlib, torch
def flat(x):
    if isinstance(x, torch.Tensor): return [x.float().flatten()]
    if isinstance(x, dict): return [t for k in sorted(x) for t in flat(x[k])]
    if isinstance(x, (list, tuple)): return [t for v in x for t in flat(v)]
    return []
a, b = pathlib.Path("/tmp/mass_ref"), pathlib.Path("/tmp/mass")
same = diff = 0
for d in sorted(a.glob("[0-9]*")):
    f, g = d / "latent.pt", b / d.name / "latent.pt"
    if f.exists() and g.exists():
        x, y = torch.cat(flat(torch.load(f, weights_only=True))), torch.cat(flat(torch.load(g, weights_only=True)))
        ok = x.shape == y.shape and bool(torch.allclose(x, y, atol=1e-3))
        same += ok; diff += not ok
print(f"resumed folder vs uninterrupted: {same} latents equal, {diff} differ")
PY
