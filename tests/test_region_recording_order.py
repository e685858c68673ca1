"""``replay --regions config`` of a recording whose entries list a tracker's scan after its later
scans, beyond ``max_lag`` (no order its live tracker took them in): one line, no traceback."""

from __future__ import annotations

import numpy as np
import pytest

from fedtrack.fusion_center.mtt.regional import recorded_pictures
from fedtrack.jsonl import InputError
from fedtrack.local_filters.mtt.config import MttConfig
from fedtrack.local_filters.mtt.scan import SensorScan
from fedtrack.local_filters.regions import grid_regions


def scan(t: float) -> SensorScan:
    return SensorScan(t, "s1", 100.0 * np.eye(2), np.array([[200.0 + 10.0 * t, 500.0]]), None, None)


def test_a_scan_listed_after_its_trackers_later_scans_is_an_input_error() -> None:
    regions = grid_regions((0.0, 0.0), (1000.0, 1000.0), 2, 1, 100.0)
    entries = [(0, (scan(t), int(t))) for t in (10.0, 11.0, 15.0)] + [(1, (scan(0.0), 0))]
    with pytest.raises(InputError, match="scan 0 of s1 .* not an order its tracker took them in"):
        list(recorded_pictures(MttConfig(), 4, True, regions, entries, {}))
