"""Numbers an agronomist reads: ground, canopy height, plants, field plots and their tables."""
