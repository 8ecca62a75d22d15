"""Where torch runs: CUDA when present and allowed, else the CPU."""

from __future__ import annotations

from contract.vocabulary import DEVICE_CHOICES as DEVICES
from contract.vocabulary import DeviceChoice


def choose_device(setting: DeviceChoice | str = "auto"):  # noqa: ANN201 - a torch.device (torch imported inside)
    """``auto``: CUDA when torch sees a GPU, else the CPU; ``cuda`` without a GPU is an
    error naming the problem."""
    import torch

    if setting not in DEVICES:
        raise ValueError(f"device {setting!r}: known devices are {', '.join(DEVICES)}")
    if setting == "cuda" and not torch.cuda.is_available():
        raise ValueError("device 'cuda': torch sees no CUDA GPU on this machine")
    if setting == "cpu" or not torch.cuda.is_available():
        return torch.device("cpu")
    return torch.device("cuda")
