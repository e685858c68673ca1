"""Progress bars for long work (tqdm on stderr, with rate and ETA).

Silent when stderr is not a terminal, so logs and CI stay clean; ``FEDTRACK_PROGRESS=1``
forces a bar (``0`` silences it).
"""

from __future__ import annotations

import os
import sys
from typing import Any

from tqdm import tqdm


def progress_bar(total: int, desc: str, **options: Any) -> tqdm:
    """A bar for ``total`` steps: ``with progress_bar(n, "label") as bar: bar.update()``; ``options``
    (``unit``, ``mininterval``, ``leave``) go to tqdm."""
    forced = os.environ.get("FEDTRACK_PROGRESS")
    show = sys.stderr.isatty() if forced is None else forced not in ("", "0")
    return tqdm(total=total, desc=desc, file=sys.stderr, disable=not show, dynamic_ncols=True,
                **{"mininterval": 0.2, "smoothing": 0.1, **options})
