#!/usr/bin/env bash
# #32 session 4, call 1 (one GPU): Individual Learning fused vs parameter sharing fused (commit $1).
set -uo pipefail
bash .gpu/b/install.sh
rm -rf /tmp/aw && mkdir -p /tmp/aw && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw/ && cp -r kernels training /tmp/aw/aquarium_warp/
export PYTHONPATH=/tmp/site:/tmp/aw GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1 AQUARIUM_WARP_COMMIT=$1
R=/tmp/p10 && rm -rf $R && mkdir -p $R && cd /tmp/aw && nvidia-smi -L
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once" ; }
trap 'tar czf $OUT/p10.tgz -C /tmp p10; ls -la $OUT' EXIT
AQUARIUM_TEST_DEVICE=cuda:0 timeout 150 python -m pytest -q -m "not slow or slow" tests/training/test_fused_ppo.py -k "cuda" -p no:cacheprovider > $R/tests_fused_ppo.log 2>&1; echo "fused_ppo rc=$?: $(tail -1 $R/tests_fused_ppo.log)"
grep -h -B5 -A30 "^E " $R/tests_*.log | head -60
echo "== IL"; timeout 200 python benchmarks/bench_training.py --device cuda:0 --worlds 1024,65536 --sharing individual --loops fast --variants fused-tf32 --warmup 2 --iterations 5 --commit $1 --out-dir $R/training_individual 2>&1 | clean | tail -6
echo "== PS"; timeout 120 python benchmarks/bench_training.py --device cuda:0 --worlds 1024,65536 --sharing parameter --loops fast --variants fused-tf32 --warmup 2 --iterations 5 --commit $1 --out-dir $R/training_parameter 2>&1 | clean | tail -6
