"""Robot controller drivers, one module per protocol family, found by name in a registry."""
