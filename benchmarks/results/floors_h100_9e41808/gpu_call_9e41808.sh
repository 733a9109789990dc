#!/usr/bin/env bash
# #32 session 4, call 3 (one GPU): kernel shapes of the update and the rollout step; profile; the paper preset (commit $1).
set -uo pipefail
bash .gpu/b/install.sh
rm -rf /tmp/aw && mkdir -p /tmp/aw && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw/ && cp -r kernels training /tmp/aw/aquarium_warp/
export PYTHONPATH=/tmp/site:/tmp/aw GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1 AQUARIUM_WARP_COMMIT=$1
R=/tmp/p12 && rm -rf $R && mkdir -p $R && cd /tmp/aw && nvidia-smi -L
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once\|USDT" ; }
trap 'tar czf $OUT/p12.tgz -C /tmp p12; ls -la $OUT' EXIT
echo "== tune"; timeout 300 python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32 --rows 16,32 --warps 2,4 --programs 2,4 --act-rows 32,64,128,256 --act-warps 4,8 --repeats 3 --commit $1 --out $R/tune_fused_cuda0.json 2>&1 | clean | tail -30
echo "== profile"; timeout 150 python benchmarks/profile_training.py --device cuda:0 --worlds 1024,65536 --variant fused-tf32 --top 12 --commit $1 --out-dir $R/profile 2>&1 | clean | tail -30
for i in 1 2; do /usr/bin/time -f "wall %e s" timeout 80 python -m aquarium_warp train --preset paper --device cuda:0 --quiet --export none --set train.fused_mlp=true --set train.tf32=true --seed 0 --log-dir $R/paper-$i 2>&1 | clean | tail -2; done
