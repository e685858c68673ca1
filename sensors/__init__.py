"""Scenarios and simulated sensors."""
