"""plantsim.sensor."""
