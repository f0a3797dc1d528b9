"""Live sessions with a robot: the identification run, stored baselines, simulated cells, watch."""
