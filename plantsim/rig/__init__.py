"""plantsim.rig."""
