"""Trajectory evaluation with the definitions of evo: association, Umeyama alignment, APE, RPE."""
