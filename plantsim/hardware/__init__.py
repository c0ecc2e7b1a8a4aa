"""plantsim.hardware."""
