"""fedtrack: distributed multi-sensor target tracking and fusion over Eclipse Zenoh.

This package is the ground plumbing (wire protocol, keys, sessions, config, JSON Lines,
service base); the estimator families, the fusion centre, simulation, deployment and
reproductions are its subpackages (see README, Layout).
"""
