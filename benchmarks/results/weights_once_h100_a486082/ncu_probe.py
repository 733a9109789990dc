"""The probe that `ncu_call.sh` ran under Nsight Compute (#32): one fused update of the paper task at
65,536 worlds with TF32 products, twice (the first compiles the kernels), then the loss kernels'
registers and spills. Run from the repository root of a staged tree."""

import sys

sys.path.insert(0, "benchmarks")

import bench_fused_update as bench
import torch
import tune_fused_kernels as tune

torch.backends.cuda.matmul.allow_tf32 = True
alg = bench.build("paper", 65536, "cuda:0")
bench.fill_storage(alg)
switch = bench.MLPSwitch(alg)
for _ in range(2):
    print("update ms", 1e3 * bench.time_update(switch, "fused", 1, graph=False), flush=True)
for k in tune.compiled_kernels():
    print(k, flush=True)
