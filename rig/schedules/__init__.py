"""Temperature schedules (steps, ramp, designed, sequential): their points, their tasks while the temperature
moves, the plan check they share, and `rig design`."""
