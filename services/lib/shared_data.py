"""Where the real sensor data shared beside the project lives (KITTI frames and scans, ROS 2
recordings): ``VISTA_SHARED_DATA``, else ``../shared/data`` beside the checkout. The
default models' build commands and the benches read their held-out real data from it; no
test or command copies it into the project."""

from __future__ import annotations

import os
from pathlib import Path

DEFAULT_SHARED_DATA = Path(__file__).resolve().parents[3] / "shared" / "data"


def shared_data_dir() -> Path:
    """``VISTA_SHARED_DATA`` if set, else ``../shared/data`` beside the checkout."""
    given = os.environ.get("VISTA_SHARED_DATA")
    return Path(given) if given else DEFAULT_SHARED_DATA


SHARED_DATA = shared_data_dir()
"""The folder as this process found it (read once, at import)."""
