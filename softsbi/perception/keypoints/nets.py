"""Networks for keypoint heatmap regression, built from ``torch.nn`` only (no torchvision).

Sources:
    * He et al., "Deep Residual Learning for Image Recognition", CVPR 2016: the ``BasicBlock``
      and the stage layout (``layers=[3, 4, 6, 3]`` is ResNet-34, ``[2, 2, 2, 2]`` ResNet-18).
    * Lin et al., "Feature Pyramid Networks for Object Detection", CVPR 2017: the top-down
      decoder with lateral (skip) connections.
    * Grannen et al., "Untangling Dense Knots by Learning Task-Relevant Keypoints", CoRL 2020 and
      Sundaresan et al., "Learning Rope Manipulation Policies Using Dense Object Descriptors
      Trained on Synthetic Depth Data", ICRA 2020: a ResNet-34 encoder regressing one Gaussian
      heatmap per keypoint, as used for the cloth keypoints of BayesSim-RKHS (Antonova et al.,
      RA-L 2022). Their decoder is a single transposed-convolution upsampling of the last stage;
      here an FPN-style decoder with skips keeps small keypoints sharp at low input resolution.

Resolution: :class:`HeatmapNet` outputs heatmaps at **half the input resolution**
(``(B, K, H/2, W/2)``): at the CPU input size of 128 px a quarter-resolution cell would span
10 px of a 320-px image (the target sigma is 6 px); the half-resolution head uses the stem
features (stride 2) as its last skip connection.
"""
from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

__all__ = ["BasicBlock", "FPNDecoder", "HeatmapNet", "ResNetBackbone"]


#: the heatmap head's initial logit: sigmoid(-4.6) ~ 0.01 everywhere
HEAD_BIAS_INIT = -4.6


def _conv_bn_relu(c_in: int, c_out: int, k: int = 3, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_out, k, stride, k // 2, bias=False), nn.BatchNorm2d(c_out),
                         nn.ReLU(inplace=True))


class BasicBlock(nn.Module):
    """ResNet basic block: two 3x3 conv-BN layers plus an identity (or 1x1-projected) shortcut.

    Args:
        c_in: input channels.
        c_out: output channels.
        stride: 1, or 2 to halve the spatial size (the shortcut is then a strided 1x1 conv).

    Shapes:
        ``(B, c_in, H, W) -> (B, c_out, ceil(H/stride), ceil(W/stride))``.
    """

    expansion = 1

    def __init__(self, c_in: int, c_out: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(c_in, c_out, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(c_out)
        self.conv2 = nn.Conv2d(c_out, c_out, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(c_out)
        self.shortcut: nn.Module = nn.Identity()
        if stride != 1 or c_in != c_out:
            self.shortcut = nn.Sequential(nn.Conv2d(c_in, c_out, 1, stride, bias=False), nn.BatchNorm2d(c_out))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        y = self.bn2(self.conv2(y))
        return F.relu(y + self.shortcut(x), inplace=True)


class ResNetBackbone(nn.Module):
    """ResNet encoder (stem + 4 stages of :class:`BasicBlock`) returning multi-scale features.

    Args:
        layers: blocks per stage (4 ints); ``[3, 4, 6, 3]`` = ResNet-34.
        width: channels of the first stage; stages have ``width * (1, 2, 4, 8)`` channels
            (64 = the standard ResNet).
        in_channels: 3 for RGB.

    Shapes:
        ``forward(x (B, in_channels, H, W))`` returns 5 feature maps
        ``[c0 (B, w, H/2, W/2), c1 (B, w, H/4, W/4), c2 (B, 2w, H/8, W/8),
        c3 (B, 4w, H/16, W/16), c4 (B, 8w, H/32, W/32)]`` (``w = width``; H, W divisible by 32).
        ``channels`` lists their channel counts.
    """

    def __init__(self, layers: Sequence[int] = (3, 4, 6, 3), width: int = 64, in_channels: int = 3):
        super().__init__()
        layers = [int(n) for n in layers]
        if len(layers) != 4 or min(layers) < 1:
            raise ValueError(f"layers must be 4 positive block counts (e.g. [3, 4, 6, 3]), got {layers}")
        if int(width) < 1:
            raise ValueError(f"width must be a positive channel count, got {width}")
        w = int(width)
        self.stem = _conv_bn_relu(in_channels, w, k=7, stride=2)
        self.pool = nn.MaxPool2d(3, 2, 1)
        chans = [w, 2 * w, 4 * w, 8 * w]
        stages = []
        c_in = w
        for i, (n, c) in enumerate(zip(layers, chans)):
            blocks = [BasicBlock(c_in, c, stride=1 if i == 0 else 2)]
            blocks += [BasicBlock(c, c) for _ in range(n - 1)]
            stages.append(nn.Sequential(*blocks))
            c_in = c
        self.stages = nn.ModuleList(stages)
        self.channels = [w] + chans

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        c0 = self.stem(x)
        feats = [c0]
        y = self.pool(c0)
        for stage in self.stages:
            y = stage(y)
            feats.append(y)
        return feats


class FPNDecoder(nn.Module):
    """Top-down decoder with lateral skips (FPN), ending at the stem resolution (input / 2).

    Each coarser map is bilinearly upsampled to the next finer one and added to a 1x1 lateral
    projection of the encoder feature there, followed by a 3x3 conv-BN-ReLU.

    Args:
        channels: encoder channels ``[c0, c1, c2, c3, c4]`` (fine to coarse).
        dec_channels: channels of every decoder map.

    Shapes:
        ``forward([c0 .. c4])`` -> ``(B, dec_channels, H0, W0)`` at the size of ``c0`` (input / 2).
    """

    def __init__(self, channels: Sequence[int], dec_channels: int = 64):
        super().__init__()
        d = int(dec_channels)
        self.lateral = nn.ModuleList([nn.Conv2d(c, d, 1) for c in channels])
        self.smooth = nn.ModuleList([_conv_bn_relu(d, d) for _ in channels[:-1]])

    def forward(self, feats: Sequence[torch.Tensor]) -> torch.Tensor:
        y = self.lateral[-1](feats[-1])
        for i in range(len(feats) - 2, -1, -1):
            skip = self.lateral[i](feats[i])
            y = F.interpolate(y, size=skip.shape[-2:], mode="bilinear", align_corners=False) + skip
            y = self.smooth[i](y)
        return y


class HeatmapNet(nn.Module):
    """ResNet encoder + FPN decoder + 1x1 head: one heatmap (logit) channel per keypoint.

    Args:
        n_keypoints: K (output channels).
        layers: blocks per ResNet stage, default ResNet-34 ``[3, 4, 6, 3]``.
        width: channels of the first ResNet stage (default 64 as in ResNet; narrower is faster).
        dec_channels: decoder channels (default: ``max(width, 16)``).

    Shapes:
        ``forward(x (B, 3, H, W))`` -> logits ``(B, K, H/2, W/2)``; ``H`` and ``W`` must be
        multiples of 32. Heatmap cell ``(i, j)`` covers input pixels ``2i..2i+1``; its centre is
        at input pixel ``2i + 0.5`` (pixel centres at integer coordinates).

    Raises:
        ValueError: H or W not a multiple of 32 (in ``forward``), bad ``layers``/``width``.
    """

    stride = 2

    def __init__(self, n_keypoints: int, layers: Sequence[int] = (3, 4, 6, 3), width: int = 64,
                 dec_channels: int | None = None):
        super().__init__()
        self.backbone = ResNetBackbone(layers, width)
        d = int(dec_channels) if dec_channels else max(int(width), 16)
        self.decoder = FPNDecoder(self.backbone.channels, d)
        self.head = nn.Sequential(_conv_bn_relu(d, d), nn.Conv2d(d, int(n_keypoints), 1))
        # start from a low heatmap everywhere: stabilises BCE on sparse targets
        nn.init.constant_(self.head[-1].bias, HEAD_BIAS_INIT)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if x.shape[-1] % 32 or x.shape[-2] % 32:
            raise ValueError(f"input height and width must be multiples of 32, got {tuple(x.shape[-2:])}")
        return self.head(self.decoder(self.backbone(x)))
