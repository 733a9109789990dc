"""#32 probe (not committed): one fused update at 65,536 worlds (TF32) whose loss kernels ncu profiles."""
import sys
sys.path.insert(0, "benchmarks")
import torch
import bench_fused_update as bench
import tune_fused_kernels as tune
torch.backends.cuda.matmul.allow_tf32 = True
alg = bench.build("paper", 65536, "cuda:0")
bench.fill_storage(alg)
switch = bench.MLPSwitch(alg)
for _ in range(2):
    print("update ms", 1e3 * bench.time_update(switch, "fused", 1, graph=False), flush=True)
for k in tune.compiled_kernels():
    print(k, flush=True)
