"""plantsim.scan."""
