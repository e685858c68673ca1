"""Linear-Gaussian building blocks: Kalman steps, motion models, one-point initialisation."""
