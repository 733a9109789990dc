#!/usr/bin/env bash
# #32 session 4 (one GPU): both teams against one team at 1,024 and 65,536 worlds, fused + TF32 (commit $1).
set -uo pipefail
bash .gpu/b/install.sh || exit 3
rm -rf /tmp/aw && mkdir -p /tmp/aw && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw/ && cp -r kernels training /tmp/aw/aquarium_warp/
export PYTHONPATH=/tmp/site:/tmp/aw GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1 AQUARIUM_WARP_COMMIT=$1
R=/tmp/p16 && rm -rf $R && mkdir -p $R && cd /tmp/aw
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once\|USDT" ; }
trap 'tar czf $OUT/p16.tgz -C /tmp p16; ls -la $OUT' EXIT
for w in 1024 65536; do echo "== $w"; timeout 250 python benchmarks/bench_multi_gpu.py --gpus 1 --teams prey,both --modes graphs --iterations 10 --num-worlds $w --timeout 110 --set train.fused_mlp=true --set train.tf32=true --commit $1 --out-dir $R/w$w 2>&1 | clean | tail -6; done
