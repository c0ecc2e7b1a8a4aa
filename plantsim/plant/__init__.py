"""The plant: mesh import and placement (:mod:`.mesh`), procedural plants with exact traits
(:mod:`.procedural`) and the calibration target (:mod:`.target`)."""
