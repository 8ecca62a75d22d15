"""The tracking service's networks, in plain torch.

- ``BevDetector``: a bird's-eye-view car detector in the manner of PIXOR and CenterPoint —
  a three-stage convolutional backbone over the twelve-channel BEV image (``bev``), one
  top-down merge back to a quarter of its resolution (0.8 m cells), and per cell a centre
  heatmap (one class: Car), the centre's offset within the cell, its height, the box's log
  size and the heading's sine and cosine.
- ``PointEncoder`` (with ``ShapeDecoder``): the Siamese tracker's PointNet (SC3D, Giancola
  et al. 2019): shared per-point layers and a max pool to one latent vector; the decoder
  rebuilds the target's complete shape from a latent (the shape-completion regulariser).
"""

from __future__ import annotations

import torch
from torch import nn

from services.tracking.bev import CHANNELS

HEADS = {"heatmap": 1, "offset": 2, "z": 1, "size": 3, "heading": 2}


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1, bias=False),
        nn.BatchNorm2d(cout),
        nn.ReLU(inplace=True),
    )


class BevDetector(nn.Module):
    """(B, 12, H, W) BEV images (H, W multiples of 16) → (B, 9, H/4, W/4): heatmap logit,
    offset (cells), z (m), log size (l, w, h in m), sin and cos of the heading."""

    def __init__(self, width: int = 32) -> None:
        super().__init__()
        self.stem = nn.Sequential(_conv(CHANNELS, width, 2), _conv(width, width))
        self.down2 = nn.Sequential(
            _conv(width, 2 * width, 2), _conv(2 * width, 2 * width), _conv(2 * width, 2 * width)
        )
        self.down3 = nn.Sequential(
            _conv(2 * width, 4 * width, 2), _conv(4 * width, 4 * width), _conv(4 * width, 4 * width)
        )
        self.up3 = nn.Sequential(
            nn.ConvTranspose2d(4 * width, 2 * width, 2, stride=2, bias=False),
            nn.BatchNorm2d(2 * width),
            nn.ReLU(inplace=True),
        )
        self.fuse = _conv(4 * width, 2 * width)
        self.shared = _conv(2 * width, 2 * width)
        self.heads = nn.ModuleDict(
            {name: nn.Conv2d(2 * width, size, 1) for name, size in HEADS.items()}
        )
        nn.init.constant_(self.heads["heatmap"].bias, -2.19)  # CenterNet's prior: sigmoid ≈ 0.1

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        quarter = self.down2(self.stem(x))
        eighth = self.down3(quarter)
        merged = self.shared(self.fuse(torch.cat([quarter, self.up3(eighth)], dim=1)))
        return torch.cat([self.heads[name](merged) for name in HEADS], dim=1)


class PointEncoder(nn.Module):
    """(B, 3, N) points in a box's frame (metres) → (B, latent) after a max pool over points."""

    def __init__(self, latent: int = 128) -> None:
        super().__init__()
        layers, cin = [], 3
        for cout in (64, 64, 128, latent):
            layers += [
                nn.Conv1d(cin, cout, 1, bias=False),
                nn.BatchNorm1d(cout),
                nn.ReLU(inplace=True),
            ]
            cin = cout
        self.layers = nn.Sequential(*layers[:-1])  # no ReLU on the last: the latent keeps its sign

    def forward(self, points: torch.Tensor) -> torch.Tensor:
        return self.layers(points).amax(dim=2)


class ShapeDecoder(nn.Module):
    """(B, latent) → (B, 3, M) a complete shape (SC3D's shape-completion branch)."""

    def __init__(self, latent: int = 128, points: int = 512) -> None:
        super().__init__()
        self.points = points
        self.layers = nn.Sequential(
            nn.Linear(latent, 256),
            nn.ReLU(inplace=True),
            nn.Linear(256, 512),
            nn.ReLU(inplace=True),
            nn.Linear(512, 3 * points),
        )

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return self.layers(latent).view(-1, 3, self.points)
