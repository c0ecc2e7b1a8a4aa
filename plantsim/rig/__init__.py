"""The rig: its geometry and frames (:mod:`.geometry`) and the MuJoCo scene built from the MJCF
rig file, the geometry and the plant (:mod:`.scene`)."""
