"""Deployment configurations (TOML) and scripts for `fedtrack launch`."""
