"""Traits from pipeline scans of procedural plants against their exact truth (issue 13).

Asserted here: the issue's targets that the current method meets (docs/traits.md has the
full table from scripts/traits_accuracy.py). Not yet met, so not asserted: maize and
rosette leaf count and area from ideal scans, and every leaf trait from realistic scans.
"""

import functools
import logging

import pytest

from plantsim.evaluation import traits
from plantsim.plant.mesh import plant_from_arrays
from plantsim.plant.procedural import make_maize, make_rosette, make_wheat
from plantsim.scan.config import RunConfig
from plantsim.scan.pipeline import run_scan
from plantsim.scan.schedule import StepScan

PLANTS = {
    "maize": lambda: make_maize(seed=0),
    "wheat": lambda: make_wheat(seed=0),
    "rosette": lambda: make_rosette(seed=2, n_leaves=30),
}


@functools.lru_cache(maxsize=None)
def _scan(name: str, ideal: bool, step_deg: float):
    plant = PLANTS[name]()
    result = run_scan(RunConfig(ideal=ideal, scan=StepScan(step_deg=step_deg)),
                      plant=plant_from_arrays(plant.vertices_m, plant.faces))
    points = result.cloud.plant_only().points_turntable
    return traits.extract_traits(points), plant.traits


def _rel(estimate, truth):
    return abs(estimate - truth) / truth


@pytest.mark.parametrize("name", sorted(PLANTS))
def test_height_from_an_ideal_half_degree_scan_within_two_percent(name, caplog):
    caplog.set_level(logging.ERROR)
    est, truth = _scan(name, True, 0.5)
    assert _rel(est.height_m, truth["height_m"]) <= 0.02


@pytest.mark.parametrize("name", sorted(PLANTS))
def test_height_from_a_realistic_one_degree_scan_within_five_percent(name, caplog):
    caplog.set_level(logging.ERROR)
    est, truth = _scan(name, False, 1.0)
    assert _rel(est.height_m, truth["height_m"]) <= 0.05


def test_wheat_tillers_leaf_count_and_area_from_an_ideal_scan_meet_the_targets(caplog):
    caplog.set_level(logging.ERROR)
    est, truth = _scan("wheat", True, 0.5)
    assert est.stem_count == len(truth["stems"]) == 4
    assert _rel(est.leaf_count, len(truth["leaves"])) <= 0.20
    assert _rel(est.leaf_area_m2, truth["leaf_area_m2"]) <= 0.20
