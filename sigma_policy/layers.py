"""The building blocks of sigma's networks: a convolution and a linear layer, each with optional GroupNorm(4) and
LeakyReLU(0.02), initialised for the activation that follows them, and the heads' dilated local encoder built from
the convolution (:mod:`sigma_policy.network`, :mod:`sigma_policy.yaw_scan`)."""

from __future__ import annotations

import torch
from torch import Tensor, nn

__all__ = ["LRELU_SLOPE", "ConvBlock", "DenseBlock", "LocalEncoder"]

LRELU_SLOPE = 0.02


def _init_for_activation(module: nn.Conv2d | nn.Linear, activation: bool) -> None:
    if activation:
        nn.init.kaiming_uniform_(module.weight, a=LRELU_SLOPE, nonlinearity="leaky_relu")
    else:
        nn.init.xavier_uniform_(module.weight, gain=1.0)
    if module.bias is not None:
        nn.init.zeros_(module.bias)


class ConvBlock(nn.Sequential):
    """Conv2d (replicate padding, ``dilation * (k // 2)``) + optional GroupNorm(4) + optional LeakyReLU(0.02).

    ``pre_padded``: the input already carries its replicate border (see :class:`sigma_policy.upsample.BilinearUpsample`), so the conv
    pads nothing. A 1x1 conv pads nothing either (replicate padding by 0 would still copy the input).

    ``channels_last``: the layout of the activations, the same values either way. None (the default) = NHWC on the
    CPU, where oneDNN's NCHW convolutions reorder every input, output and gradient to a blocked layout and back (a
    `small` training step on 2 AVX2 cores: 1.11-1.16x faster in NHWC, docs/learning.md "Training speed"), and NCHW
    elsewhere (on an H100 NHWC did not help in eager mode, docs/gpu.md).
    """

    channels_last: bool | None = None

    def __init__(
        self,
        c_in: int,
        c_out: int,
        kernel: int,
        stride: int = 1,
        norm: bool = False,
        act: bool = True,
        pre_padded: bool = False,
        dilation: int = 1,
    ):
        pad = 0 if stride > 1 or pre_padded else dilation * (kernel // 2)
        conv = nn.Conv2d(c_in, c_out, kernel, stride, padding=pad, dilation=dilation)
        if pad:
            conv.padding_mode = "replicate"
        _init_for_activation(conv, act)
        layers: list[nn.Module] = [conv]
        if norm:
            layers.append(nn.GroupNorm(4, c_out))
        if act:
            layers.append(nn.LeakyReLU(LRELU_SLOPE))
        super().__init__(*layers)

    def forward(self, x: Tensor) -> Tensor:
        nhwc = x.device.type == "cpu" if self.channels_last is None else self.channels_last
        return super().forward(x.contiguous(memory_format=torch.channels_last) if nhwc else x)


class DenseBlock(nn.Module):
    """Linear + optional GroupNorm(4) over features (tokens are folded into the batch) + optional LeakyReLU."""

    def __init__(self, d_in: int, d_out: int, norm: bool = False, act: bool = True):
        super().__init__()
        self.linear = nn.Linear(d_in, d_out)
        _init_for_activation(self.linear, act)
        self.norm = nn.GroupNorm(4, d_out) if norm else None
        self.act = nn.LeakyReLU(LRELU_SLOPE) if act else None

    def forward(self, x: Tensor) -> Tensor:
        x = self.linear(x)
        if self.norm is not None:
            shape = x.shape
            x = self.norm(x.reshape(-1, shape[-1])).reshape(shape)
        return self.act(x) if self.act is not None else x


class LocalEncoder(nn.Sequential):
    """Full-resolution 3x3 convolutions with growing dilation on a rendered view: (BV, C_in, H, W) ->
    (BV, channels, H, W). With dilations (1, 2, 4, 8) each output pixel sees 31 x 31 input pixels, a 4 cm cube
    and its surroundings in the ``small`` preset's 5.6 mm pixels; being convolutional, the same outline gives the
    same features wherever it lies in the view."""

    def __init__(self, c_in: int, channels: int, dilations: tuple[int, ...]):
        super().__init__(
            *(
                ConvBlock(c_in if i == 0 else channels, channels, 3, dilation=d)
                for i, d in enumerate(dilations)
            )
        )
