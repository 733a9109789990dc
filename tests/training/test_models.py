"""Individual Learning's batched layers: the chunked weight gradient against the plain float64 products."""

import os

os.environ.setdefault("GIT_PYTHON_REFRESH", "quiet")

import pytest
import torch

from aquarium_warp.training.models import WEIGHT_GRAD_CHUNK, BatchedLinear, BatchedMLP


@pytest.mark.parametrize(
    "rows",
    [3 * WEIGHT_GRAD_CHUNK, WEIGHT_GRAD_CHUNK, WEIGHT_GRAD_CHUNK + 7, 5],
    ids=["chunked", "one chunk", "not a multiple", "few rows"],
)
def test_batched_linear_gradients_equal_plain_products(rows):
    gen = torch.Generator().manual_seed(rows)
    layer = BatchedLinear(3, 29, 16).double()
    x = torch.randn(3, rows, 29, dtype=torch.float64, generator=gen, requires_grad=True)
    upstream = torch.randn(3, rows, 16, dtype=torch.float64, generator=gen)
    out = layer(x)
    out.backward(upstream)
    w, b = layer.weight.detach(), layer.bias.detach()
    assert torch.allclose(out, torch.bmm(x.detach(), w) + b.unsqueeze(1))
    assert torch.allclose(layer.weight.grad, torch.bmm(x.detach().transpose(1, 2), upstream), rtol=1e-12, atol=1e-12)
    assert torch.allclose(layer.bias.grad, upstream.sum(dim=1), rtol=1e-12, atol=1e-12)
    assert torch.allclose(x.grad, torch.bmm(upstream, w.transpose(1, 2)), rtol=1e-12, atol=1e-12)


def test_batched_mlp_scripts_for_export():
    mlp = BatchedMLP(2, 5, 4, [8, 8], "tanh")
    x = torch.randn(6, 5)
    with torch.no_grad():
        assert torch.equal(torch.jit.script(mlp)(x), mlp(x))
