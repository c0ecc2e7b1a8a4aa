"""Clouds: reconstruction from a raw record (:mod:`.reconstruct`), file formats
(:mod:`.export`), outputs written as a unit (:mod:`.outputs`), the raw record as a ROS 2 bag
(:mod:`.bag`) and rig calibration from a scan of the target (:mod:`.calibration`)."""
