#!/usr/bin/env bash
# #32 session 4, call 5 (one GPU): the weights loaded once per program: before (a486082) and after (working tree).
set -uo pipefail
bash .gpu/b/install.sh
for t in old new; do rm -rf /tmp/aw_$t && mkdir -p /tmp/aw_$t; done
tar xf .gpu/b/old.tar -C /tmp/aw_old && cp -r aquarium_warp benchmarks tests pyproject.toml /tmp/aw_new/ && cp -r kernels training /tmp/aw_new/aquarium_warp/
(cd /tmp/aw_old && cp -r kernels training aquarium_warp/)
export GIT_PYTHON_REFRESH=quiet NCCL_NVLS_ENABLE=0 PYTHONUNBUFFERED=1
R=/tmp/p14 && rm -rf $R && mkdir -p $R
clean() { grep -v "^Warp\|^   CUDA\|^   Devices\|^     \"\|^   Kernel cache\|^     /root\|^Module\|it/s\|UserWarning\|_warn_once\|return Variable\|AccumulateGrad\|FP_FUSION\|warn_once\|USDT" ; }
trap 'tar czf $OUT/p14.tgz -C /tmp p14; ls -la $OUT' EXIT
for t in old new; do
  echo "== tune $t"; (cd /tmp/aw_$t && PYTHONPATH=/tmp/site:/tmp/aw_$t timeout 200 python benchmarks/tune_fused_kernels.py --device cuda:0 --worlds 65536 --tf32 --rows 32,64 --warps 4 --programs 2 --act-rows 64 --act-warps 4 --repeats 5 --out $R/tune_$t.json 2>&1 | clean | grep -v "fast tanh False" | tail -6)
done
if [ -n "${1:-}" ]; then cd /tmp/aw_new && PYTHONPATH=/tmp/site:/tmp/aw_new AQUARIUM_TEST_DEVICE=cuda:0 timeout 200 python -m pytest -q -m "not slow or slow" tests/training/test_fused_ppo.py tests/training/test_fused_mlp.py -k cuda -p no:cacheprovider > $R/tests.log 2>&1; echo "tests rc=$?: $(tail -1 $R/tests.log)"; fi
