"""Where the public (mesh, cage) pairs of bench/public-data.md are on this machine: $LBC_PUBLIC_DATA, or None."""

import os
from pathlib import Path


def public_data():
    """The folder named by LBC_PUBLIC_DATA, or None when it is unset (the benchmarks then use tests/data alone)."""
    folder = os.environ.get("LBC_PUBLIC_DATA")
    return Path(folder) if folder else None
