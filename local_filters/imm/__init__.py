"""IMM trackers (paper 000): FSIMM, VSIMM, activation-only VSIMM; replay and service."""
