"""plantsim.evaluation."""
