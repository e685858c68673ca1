"""3-D radar EKF variants (papers 002, 003): measurement model, EKF, input estimation, TS-fuzzy."""
