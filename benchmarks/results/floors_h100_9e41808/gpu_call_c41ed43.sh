#!/usr/bin/env bash
# #32 session 4, call 2 (one GPU): the rollout's floor and one iteration's kernels (commit $1).
set -uo pipefail
bash .gpu/b/install.sh
rm -rf /tmp/aw && mkdir -p /tmp/aw && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw/ && cp -r kernels training /tmp/aw/aquarium_warp/
export PYTHONPATH=/tmp/site:/tmp/aw GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1 AQUARIUM_WARP_COMMIT=$1
R=/tmp/p11 && rm -rf $R && mkdir -p $R && cd /tmp/aw && nvidia-smi -L
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once\|USDT" ; }
trap 'tar czf $OUT/p11.tgz -C /tmp p11; ls -la $OUT' EXIT
echo "== bench"; timeout 240 python benchmarks/bench_training.py --device cuda:0 --worlds 1024,65536 --sharing parameter,individual --loops fast --variants fused-tf32 --warmup 2 --iterations 5 --commit $1 --out-dir $R/training 2>&1 | clean | tail -8
echo "== profile"; timeout 200 python benchmarks/profile_training.py --device cuda:0 --worlds 1024,65536 --variant fused-tf32 --top 22 --commit $1 --out-dir $R/profile 2>&1 | clean | tail -52
