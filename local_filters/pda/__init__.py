"""Cluttered-sensor tracking (paper 001): PDA-AI, HPDA, track initiation; replay and service."""
