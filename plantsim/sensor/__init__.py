"""The LiDAR: specs and presets (:mod:`.spec`), the beam footprint (:mod:`.footprint`), the sensor
model of noise, intensity and dropouts (:mod:`.model`), ray casting (:mod:`.casting`), and the
simulated LiDAR that puts them together as a line source (:mod:`.lidar`)."""
