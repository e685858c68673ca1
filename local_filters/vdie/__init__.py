"""Variable-dimension input estimation (paper 004): VDIE maths, the [fusion] config, the distributed local filters."""
