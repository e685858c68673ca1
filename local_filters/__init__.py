"""Local (per-sensor) estimators: Kalman core, IMM, PDA/HPDA, radar EKFs."""
