"""plantsim.plant."""
