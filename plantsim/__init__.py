"""plantsim: a MuJoCo simulator of a 2D-LiDAR + turntable plant-phenotyping scanner."""

from plantsim.errors import (
    ConfigError,
    HardwareError,
    MeshError,
    PlantSimError,
    SceneError,
    SimulationError,
)

__version__ = "0.1.0"
