"""Multi-target fusion: track-to-track centre with out-of-sequence buffers, engines, replay."""
