"""Colon simulator: procedural colons, withdrawal trajectories, rendering, datasets."""
