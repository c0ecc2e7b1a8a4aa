"""plantsim.turntable."""
