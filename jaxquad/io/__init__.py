"""File formats: TUM trajectories, robot logs (.npz), occupancy maps (PGM + YAML)."""
