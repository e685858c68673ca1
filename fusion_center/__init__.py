"""Fusion of local estimates: centralized, federated (with reset), decentralized; VDIE."""
