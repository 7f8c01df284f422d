"""MJX fleet simulator: robots walking through generated worlds, with the sensors the estimators use."""
