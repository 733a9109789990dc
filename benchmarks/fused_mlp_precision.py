"""The fused MLP's accuracy per product precision, beside torch's own MLP: relative errors (max |value -
float64| / max |float64|) of the forward and of the worst parameter gradient of one MLP (default
29-64-64-9 tanh, the actor of the paper preset) on `--rows` random rows.

Precisions on CUDA: float32 as `ieee` (float32 multiply-adds) and as `tf32x3` (three TF32 products,
the default, `training.fused_mlp.FLOAT32_PRECISION`), and TF32 (`torch.backends.cuda.matmul.allow_tf32`,
which `train.tf32` sets; torch's float32 then uses TF32 too). On the CPU the kernels run only under
Triton's interpreter (`TRITON_INTERPRET=1`), which computes `ieee` whatever is asked.

    python benchmarks/fused_mlp_precision.py --device cuda:0 --rows 1000003
    TRITON_INTERPRET=1 python benchmarks/fused_mlp_precision.py --device cpu --rows 200

Prints a table and writes `fused_mlp_precision_<device>.json` (atomically) into `--out-dir`, with the
command, the commit (`--commit` where git is not available), the machine and the library versions.
"""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from rsl_rl.modules import MLP

from aquarium_warp.atomic import atomic_open
from aquarium_warp.records import command_line, provenance
from aquarium_warp.training import fused_mlp

CASES = (("ieee", False), ("tf32x3", False), ("tf32", True))  # (float32 precision, TF32 allowed)


def relative_error(value: torch.Tensor, reference: torch.Tensor) -> float:
    return float((value.detach().double() - reference.detach()).abs().max() / reference.detach().abs().max())


def errors(device: str, rows: int, seed: int = 0) -> list[dict]:
    """Each case's forward and worst parameter-gradient errors, fused and torch's."""
    torch.manual_seed(seed)
    mlp = MLP(29, 9, [64, 64], "tanh").to(device)
    fused = fused_mlp.FusedMLP(copy.deepcopy(mlp))
    reference = copy.deepcopy(mlp).double()
    x = torch.randn(rows, 29, device=device)
    grad = torch.randn(rows, 9, device=device)
    y_ref = reference(x.double())
    y_ref.backward(grad.double())
    out = []
    allow_tf32, precision = torch.backends.cuda.matmul.allow_tf32, fused_mlp.FLOAT32_PRECISION
    try:
        for float32_precision, tf32 in CASES:
            torch.backends.cuda.matmul.allow_tf32 = tf32
            fused_mlp.FLOAT32_PRECISION = float32_precision
            row = {"precision": "tf32" if tf32 else float32_precision}
            for name, model in (("fused", fused), ("torch", copy.deepcopy(mlp))):
                model.zero_grad(set_to_none=True)
                y = model(x)
                y.backward(grad)
                row[f"{name}_forward"] = relative_error(y, y_ref)
                row[f"{name}_gradients"] = max(
                    relative_error(p.grad, q.grad) for p, q in zip(model.parameters(), reference.parameters())
                )
            out.append(row)
    finally:
        torch.backends.cuda.matmul.allow_tf32, fused_mlp.FLOAT32_PRECISION = allow_tf32, precision
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--device", default="cuda:0")
    parser.add_argument("--rows", type=int, default=1_000_003)
    parser.add_argument("--commit", default=None, help="the commit measured, for a copy without git history")
    parser.add_argument("--out-dir", type=Path, default=Path("."))
    args = parser.parse_args(argv)
    if args.rows < 1:
        parser.error(f"--rows={args.rows} must be >= 1")
    if torch.device(args.device).type not in fused_mlp.DEVICES:
        parser.error(f"--device={args.device}: the fused kernels take {list(fused_mlp.DEVICES)} tensors here")
    rows = errors(args.device, args.rows)
    print(f"{'precision':>9} {'fused forward':>13} {'fused grads':>11} {'torch forward':>13} {'torch grads':>11}")
    for r in rows:
        print(
            f"{r['precision']:>9} {r['fused_forward']:13.2e} {r['fused_gradients']:11.2e} "
            f"{r['torch_forward']:13.2e} {r['torch_gradients']:11.2e}"
        )
    record = {
        "benchmark": "fused_mlp_precision",
        "rows": args.rows,
        "mlp": "29-64-64-9 tanh",
        "interpreted": fused_mlp.INTERPRETED,
        "cases": rows,
        **provenance(args.device, command_line(argv, Path(__file__).name), args.commit),
    }
    args.out_dir.mkdir(parents=True, exist_ok=True)
    path = args.out_dir / f"fused_mlp_precision_{args.device.replace(':', '')}.json"
    with atomic_open(path) as f:
        json.dump(record, f, indent=2)
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
