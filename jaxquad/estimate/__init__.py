"""Contact estimation and leg-inertial odometry over robot logs, scoring and tuning."""
