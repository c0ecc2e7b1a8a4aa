"""plantsim.cloud."""
