"""The building blocks: a convolution block gives the same values and gradients in either activation layout."""

from __future__ import annotations

import pytest
import torch

from sigma_policy.layers import ConvBlock


@pytest.mark.parametrize(
    "kwargs",
    [
        {"kernel": 3, "dilation": 4},  # replicate border, as in the local encoder
        {"kernel": 8, "stride": 8, "norm": True},  # the patch convolution with its GroupNorm
        {"kernel": 1, "act": False},
    ],
)
def test_conv_block_is_the_same_function_in_nhwc_and_nchw(kwargs):
    torch.manual_seed(0)
    block = ConvBlock(10, 16, **kwargs)
    x = torch.randn(3, 10, 32, 32)
    results = {}
    for layout in (False, True):
        block.channels_last = layout
        block.zero_grad()
        xi = x.clone().requires_grad_()
        out = block(xi)
        (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
        results[layout] = (out, xi.grad, block[0].weight.grad.clone())
        assert out.is_contiguous(memory_format=torch.channels_last) == layout
    for nchw, nhwc in zip(results[False], results[True], strict=True):
        # The weight gradient sums 3 x 32 x 32 products per entry in another order per layout (up to 2e-4 apart at a
        # scale of 130 on an AVX-512 CPU): the tolerance follows each tensor's scale, far below a layout mix-up's.
        scale = max(1.0, nchw.abs().max().item())
        torch.testing.assert_close(nhwc, nchw, rtol=1e-4, atol=1e-5 * scale)


def test_conv_block_runs_nhwc_on_the_cpu_by_default():
    out = ConvBlock(4, 8, kernel=3)(torch.randn(2, 4, 16, 16))
    assert out.is_contiguous(memory_format=torch.channels_last)
