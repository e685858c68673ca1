"""Multi-target tracking: the ``[mtt]`` config, scans of 2-D and radar sensors, the local GNN tracker."""
