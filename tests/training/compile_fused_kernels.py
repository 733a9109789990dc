"""Compiles every fused kernel (training/fused_mlp.py, training/fused_ppo.py) to a CUDA binary for one
target, without a GPU: Triton's code generator and ptxas check what the interpreter does not (e.g. a
jit function reading a global that is not a constexpr, or the inline tanh). Run by
test_fused_ppo.py in a process without TRITON_INTERPRET; prints one line per kernel and precision.

    python tests/training/compile_fused_kernels.py [capability, default 90]
"""

import os
import sys

os.environ.pop("TRITON_INTERPRET", None)

import triton
from triton.backends.compiler import GPUTarget
from triton.compiler import ASTSource

from aquarium_warp.training import fused_mlp, fused_ppo

ACTOR = {"IN": 29, "IN_P": 32, "H": 64, "OUT": 9, "OUT_P": 16, "HIDDEN": 2, "ACTIVATION": "tanh", "BLOCK_M": 32}
SHARED = {"GROUPS": 1, "TRANSPOSED": False}  # parameter sharing's one network
STACKED = {"GROUPS": 6, "TRANSPOSED": True}  # Individual Learning's networks (models.BatchedMLP)
KERNELS = [  # (kernel, its own compile-time arguments, integer and float runtime arguments)
    (fused_mlp._forward_kernel, {"BLOCK_M": 64}, {"n_rows"}, set()),
    (fused_mlp._backward_kernel, {"GRAD_X": True}, {"n_rows"}, set()),
] + [
    (kernel, {**own, **networks}, ints, floats)
    for networks in (SHARED, STACKED)
    for kernel, own, ints, floats in [
        (fused_ppo._actor_loss_kernel, {"SUMS": 2, "NORMALIZE_ADVANTAGES": True}, {"offset", "n_rows"},
         {"clip", "entropy_coef", "inv_rows"}),
        (fused_ppo._critic_loss_kernel, {"OUT": 1, "SUMS": 1, "CLIPPED": True}, {"offset", "n_rows"},
         {"clip", "value_coef", "inv_rows"}),
        (fused_ppo._act_kernel, {"BLOCK_M": 64, "CRITIC_H": 64, "CRITIC_HIDDEN": 2, "CRITIC_ACTIVATION": "tanh"},
         {"n_rows"}, set()),
    ]
]  # fmt: skip


def compile_kernel(kernel, constants: dict, ints: set, floats: set, capability: int):
    signature = {}
    for name in kernel.arg_names:
        if name in constants:
            signature[name] = "constexpr"
        elif name in ints:
            signature[name] = "i32"
        elif name in floats:
            signature[name] = "fp32"
        else:
            signature[name] = {"index_ptr": "*i64", "env_action_ptr": "*i32"}.get(name, "*fp32")
    constexprs = {(kernel.arg_names.index(n),): v for n, v in constants.items()}
    source = ASTSource(fn=kernel, signature=signature, constexprs=constexprs)
    return triton.compile(source, target=GPUTarget("cuda", capability, 32), options={"num_warps": fused_mlp.NUM_WARPS})


def main(capability: int) -> int:
    for precision, fast_tanh in (("tf32x3", False), ("tf32", True)):
        for kernel, own, ints, floats in KERNELS:
            constants = {**ACTOR, "PRECISION": precision, "FAST_TANH": fast_tanh, **own}
            compiled = compile_kernel(kernel, constants, ints, floats, capability)
            networks = f" x{own['GROUPS']}" if own.get("GROUPS", 1) > 1 else ""
            size = len(compiled.asm["cubin"])
            print(f"{kernel.fn.__name__}{networks} {precision} sm_{capability}: {size} bytes of cubin")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 90))
