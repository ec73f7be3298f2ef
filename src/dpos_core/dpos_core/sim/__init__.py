"""Flight and sensor simulator: truth trajectories, wing flexure, sensor error models, scenarios."""
