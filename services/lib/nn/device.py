"""Where torch runs: CUDA when present and allowed, else the CPU; on how many threads."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

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


@contextmanager
def torch_threads(threads: int) -> Iterator[None]:
    """torch's intra-op threads set to ``threads`` while the block runs and given back
    after, so a library function never leaves the process's thread count changed."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        yield
    finally:
        torch.set_num_threads(before)
