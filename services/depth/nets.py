"""The depth service's networks, in plain torch (no torchvision).

- ``Student``: DeepLabv3+ (Chen et al. 2018) on a MobileNetV2 backbone (Sandler et al. 2018)
  at output stride 16 — atrous separable ASPP (rates 6, 12, 18 and image pooling), a decoder
  joining the stride-4 low-level features — as the thesis's student (5.2.2, 2.64 M
  parameters).
- ``Teacher``: Monodepth2's depth network (Godard et al. 2019): a ResNet-18 encoder and a
  U-Net decoder of ELU up-convolutions with skip connections, disparity at four scales.
- ``PoseNet``: Monodepth2's pose network for monocular training: a ResNet-18 encoder over
  two stacked frames and a small head giving an axis-angle rotation and a translation.

Every depth network takes RGB in 0–1, (N, 3, H, W) with H and W multiples of 32, normalises
it itself, and answers depth in metres, (N, 1, H, W), between ``MIN_DEPTH_M`` and
``MAX_DEPTH_M`` (Monodepth2's sigmoid disparity: depth = 1 / (1/max + (1/min − 1/max)·σ)).
In training mode a network also answers its intermediate results (``forward_train``).
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

MIN_DEPTH_M = 0.1
MAX_DEPTH_M = 100.0
MEAN, STD = 0.45, 0.225
"""Input normalisation (Monodepth2's)."""


def disparity_to_depth(sigmoid: torch.Tensor) -> torch.Tensor:
    """Depth in metres from a sigmoid output in 0–1 (Monodepth2's ``disp_to_depth``)."""
    low, high = 1 / MAX_DEPTH_M, 1 / MIN_DEPTH_M
    return 1 / (low + (high - low) * sigmoid)


def conv_bn(
    cin: int,
    cout: int,
    kernel: int = 3,
    stride: int = 1,
    dilation: int = 1,
    groups: int = 1,
    act: bool = True,
) -> nn.Sequential:
    padding = dilation * (kernel - 1) // 2
    layers: list[nn.Module] = [
        nn.Conv2d(cin, cout, kernel, stride, padding, dilation=dilation, groups=groups, bias=False),
        nn.BatchNorm2d(cout),
    ]
    if act:
        layers.append(nn.ReLU6(inplace=True))
    return nn.Sequential(*layers)


class InvertedResidual(nn.Module):
    """MobileNetV2's block: expand 1×1, depthwise 3×3 (strided or dilated), project 1×1."""

    def __init__(self, cin: int, cout: int, stride: int, expand: int, dilation: int = 1) -> None:
        super().__init__()
        hidden = cin * expand
        layers: list[nn.Module] = []
        if expand != 1:
            layers.append(conv_bn(cin, hidden, 1))
        layers += [
            conv_bn(hidden, hidden, 3, stride, dilation, groups=hidden),
            conv_bn(hidden, cout, 1, act=False),
        ]
        self.body = nn.Sequential(*layers)
        self.residual = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x) if self.residual else self.body(x)


MOBILENET_V2 = (
    (1, 16, 1, 1),
    (6, 24, 2, 2),
    (6, 32, 3, 2),
    (6, 64, 4, 2),
    (6, 96, 3, 1),
    (6, 160, 3, 2),
    (6, 320, 1, 1),
)
"""(expansion, channels, blocks, stride) of each stage."""
OUTPUT_STRIDE = 16


class MobileNetV2(nn.Module):
    """The backbone at output stride 16: the last strided stage dilates instead. Answers the
    stride-4 low-level features (24 channels) and the stride-16 ones (320)."""

    def __init__(self) -> None:
        super().__init__()
        blocks: list[nn.Module] = [conv_bn(3, 32, 3, 2)]
        cin, current_stride, dilation = 32, 2, 1
        self.low_level_index = 0
        for expand, cout, count, stride in MOBILENET_V2:
            previous = dilation
            if stride == 2 and current_stride == OUTPUT_STRIDE:
                stride, dilation = 1, dilation * 2
            else:
                current_stride *= stride
            for k in range(count):
                blocks.append(
                    InvertedResidual(
                        cin, cout, stride if k == 0 else 1, expand, previous if k == 0 else dilation
                    )
                )
                cin = cout
            if cout == 24:
                self.low_level_index = len(blocks)
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        low = x
        for i, block in enumerate(self.blocks):
            x = block(x)
            if i + 1 == self.low_level_index:
                low = x
        return low, x


class SeparableConv(nn.Sequential):
    """A depthwise (atrous) 3×3 then a pointwise 1×1, each with batch norm and ReLU."""

    def __init__(self, cin: int, cout: int, dilation: int = 1) -> None:
        super().__init__(
            nn.Conv2d(cin, cin, 3, 1, dilation, dilation=dilation, groups=cin, bias=False),
            nn.BatchNorm2d(cin),
            nn.ReLU(inplace=True),
            nn.Conv2d(cin, cout, 1, bias=False),
            nn.BatchNorm2d(cout),
            nn.ReLU(inplace=True),
        )


class ASPP(nn.Module):
    """Atrous spatial pyramid pooling with separable convolutions and image pooling."""

    def __init__(self, cin: int, channels: int, rates: tuple[int, ...] = (6, 12, 18)) -> None:
        super().__init__()
        self.branches = nn.ModuleList(
            [
                nn.Sequential(
                    nn.Conv2d(cin, channels, 1, bias=False),
                    nn.BatchNorm2d(channels),
                    nn.ReLU(inplace=True),
                )
            ]
            + [SeparableConv(cin, channels, rate) for rate in rates]
        )
        self.pooled = nn.Sequential(nn.Conv2d(cin, channels, 1, bias=False), nn.ReLU(inplace=True))
        self.project = nn.Sequential(
            nn.Conv2d(channels * (len(rates) + 2), channels, 1, bias=False),
            nn.BatchNorm2d(channels),
            nn.ReLU(inplace=True),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        outputs = [branch(x) for branch in self.branches]
        pooled = self.pooled(x.mean(dim=(2, 3), keepdim=True))
        outputs.append(pooled.expand(-1, -1, x.shape[2], x.shape[3]))
        return self.project(torch.cat(outputs, dim=1))


class Student(nn.Module):
    """DeepLabv3+ with MobileNetV2, regressing depth (module docstring)."""

    def __init__(self, aspp_channels: int = 256, decoder_channels: int = 192) -> None:
        super().__init__()
        self.backbone = MobileNetV2()
        self.aspp = ASPP(320, aspp_channels)
        self.reduce = nn.Sequential(
            nn.Conv2d(24, 48, 1, bias=False), nn.BatchNorm2d(48), nn.ReLU(inplace=True)
        )
        self.decoder = nn.Sequential(
            SeparableConv(aspp_channels + 48, decoder_channels),
            SeparableConv(decoder_channels, decoder_channels),
        )
        self.head = nn.Conv2d(decoder_channels, 1, 1)

    def forward_train(self, rgb: torch.Tensor) -> dict[str, torch.Tensor]:
        """Depth (metres, input size), the sigmoid disparity at a quarter size and the
        features distillation may match: ``low`` (stride 4), ``encoder`` (ASPP, stride 16),
        ``decoder`` (stride 4)."""
        low, deep = self.backbone((rgb - MEAN) / STD)
        encoder = self.aspp(deep)
        up = F.interpolate(encoder, size=low.shape[2:], mode="bilinear", align_corners=False)
        decoder = self.decoder(torch.cat((up, self.reduce(low)), dim=1))
        disparity = torch.sigmoid(self.head(decoder))
        full = F.interpolate(disparity, size=rgb.shape[2:], mode="bilinear", align_corners=False)
        return {
            "depth": disparity_to_depth(full),
            "disparity": full,
            "low": low,
            "encoder": encoder,
            "decoder": decoder,
        }

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.forward_train(rgb)["depth"]


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.shortcut = (
            nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
            if stride != 1 or cin != cout
            else nn.Identity()
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = F.relu(self.bn1(self.conv1(x)), inplace=True)
        return F.relu(self.bn2(self.conv2(y)) + self.shortcut(x), inplace=True)


class ResNet18(nn.Module):
    """ResNet-18's convolutional part; answers the features at strides 2, 4, 8, 16, 32."""

    CHANNELS = (64, 64, 128, 256, 512)

    def __init__(self, in_channels: int = 3) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(in_channels, 64, 7, 2, 3, bias=False),
            nn.BatchNorm2d(64),
            nn.ReLU(inplace=True),
        )
        self.pool = nn.MaxPool2d(3, 2, 1)
        layers, cin = [], 64
        for cout, stride in zip(self.CHANNELS[1:], (1, 2, 2, 2), strict=True):
            layers.append(nn.Sequential(BasicBlock(cin, cout, stride), BasicBlock(cout, cout, 1)))
            cin = cout
        self.layers = nn.ModuleList(layers)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        features = [self.stem(x)]
        x = self.pool(features[0])
        for layer in self.layers:
            x = layer(x)
            features.append(x)
        return features


class ConvELU(nn.Sequential):
    def __init__(self, cin: int, cout: int) -> None:
        super().__init__(nn.ReflectionPad2d(1), nn.Conv2d(cin, cout, 3), nn.ELU(inplace=True))


class Teacher(nn.Module):
    """Monodepth2's depth network (module docstring)."""

    DECODER = (16, 32, 64, 128, 256)

    def __init__(self) -> None:
        super().__init__()
        self.encoder = ResNet18()
        skips = ResNet18.CHANNELS
        self.up = nn.ModuleList()
        self.fuse = nn.ModuleList()
        self.heads = nn.ModuleDict()
        cin = skips[-1]
        for level in range(4, -1, -1):
            cout = self.DECODER[level]
            self.up.append(ConvELU(cin, cout))
            self.fuse.append(ConvELU(cout + (skips[level - 1] if level > 0 else 0), cout))
            if level < 4:
                self.heads[str(level)] = nn.Sequential(nn.ReflectionPad2d(1), nn.Conv2d(cout, 1, 3))
            cin = cout

    def forward_train(self, rgb: torch.Tensor) -> dict[str, torch.Tensor]:
        """Depth (metres, input size), sigmoid disparities at scales 0–3 (``disparity``,
        ``disparity_1`` … at 1/2, 1/4, 1/8 size) and the decoder's features at strides 4
        (``decoder``) and 16 (``encoder``)."""
        features = self.encoder((rgb - MEAN) / STD)
        x = features[-1]
        out: dict[str, torch.Tensor] = {"encoder": features[3]}
        for step, level in enumerate(range(4, -1, -1)):
            x = F.interpolate(self.up[step](x), scale_factor=2.0, mode="nearest")
            if level > 0:
                x = torch.cat((x, features[level - 1]), dim=1)
            x = self.fuse[step](x)
            if level == 2:
                out["decoder"] = x
            if str(level) in self.heads:
                disparity = torch.sigmoid(self.heads[str(level)](x))
                out["disparity" if level == 0 else f"disparity_{level}"] = disparity
        out["depth"] = disparity_to_depth(out["disparity"])
        return out

    def forward(self, rgb: torch.Tensor) -> torch.Tensor:
        return self.forward_train(rgb)["depth"]


class PoseNet(nn.Module):
    """Relative pose of the second frame of a pair from the first's camera: (N, 6), an
    axis-angle rotation (radians) and a translation (metres), scaled by 0.01 as Monodepth2's."""

    def __init__(self) -> None:
        super().__init__()
        self.encoder = ResNet18(in_channels=6)
        self.head = nn.Sequential(
            nn.Conv2d(512, 256, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 256, 3, 1, 1),
            nn.ReLU(inplace=True),
            nn.Conv2d(256, 6, 1),
        )

    def forward(self, first: torch.Tensor, second: torch.Tensor) -> torch.Tensor:
        x = torch.cat(((first - MEAN) / STD, (second - MEAN) / STD), dim=1)
        return 0.01 * self.head(self.encoder(x)[-1]).mean(dim=(2, 3))


def parameters(model: nn.Module) -> int:
    """Trainable parameters."""
    return sum(p.numel() for p in model.parameters() if p.requires_grad)
