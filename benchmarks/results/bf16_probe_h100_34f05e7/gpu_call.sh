#!/usr/bin/env bash
# #32 probe (one GPU): the fused update with bfloat16 products (a patched copy of fused_mlp.py) against TF32.
set -uo pipefail
bash .gpu/b/install.sh || exit 3
for t in tf32 bf16; do rm -rf /tmp/aw_$t && mkdir -p /tmp/aw_$t && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw_$t/ && cp -r kernels training /tmp/aw_$t/aquarium_warp/; done
cp .gpu/b/bf16/fused_mlp.py /tmp/aw_bf16/aquarium_warp/training/fused_mlp.py
export GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1
R=/tmp/p15 && rm -rf $R && mkdir -p $R
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once\|USDT" ; }
trap 'tar czf $OUT/p15.tgz -C /tmp p15; ls -la $OUT' EXIT
echo "== tune tf32"; (cd /tmp/aw_tf32 && PYTHONPATH=/tmp/site:/tmp/aw_tf32 timeout 120 python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32 --rows 32 --warps 4 --programs 2 --act-rows 64 --act-warps 4 --repeats 5 --commit $1 --out $R/tune_tf32.json 2>&1 | clean | grep -v "tanh False" | tail -4)
echo "== tune bf16"; (cd /tmp/aw_bf16 && PYTHONPATH=/tmp/site:/tmp/aw_bf16 timeout 300 python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32 --rows 32,64,128 --warps 4,8 --programs 2 --act-rows 64,128 --act-warps 4 --repeats 5 --out $R/tune_bf16.json 2>&1 | clean | grep -v "tanh False" | tail -12)
