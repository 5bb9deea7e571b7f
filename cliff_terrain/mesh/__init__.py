"""From heights to a mesh: the grid, the adaptive TIN, seams and orthomosaic tiles."""
