"""Robot descriptions (MJCF) and their loader."""
