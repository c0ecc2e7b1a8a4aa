"""Trait extraction on the bundled plants, against their exact traits.

Each bundled plant is scanned ideally (perfect geometry) at 0.5 degrees, the full
pipeline's cloud is reduced to its plant points, and ``extract_traits`` runs on it
without the mesh. The stated tolerances, against ``assets/<plant>.traits.json``:

- height within 2 % (the top of the plant is seen by few beams);
- stem diameter within 10 %, every stem's and the mean (a circle fit on the
  half of the stem the beams see at a time, turned through 360 degrees);
- each stem centre within 1 mm of its base, and distances between stems within
  10 % (wheat: 4 tillers);
- largest leaf width within 20 %.

Leaves are separated with ``leaf_link_distance`` 3 mm (a dense scan's setting: at
0.5 degrees neighbouring points on a leaf lie about 1-3 mm apart). The default 6 mm
joins the wheat's touching leaves into one wide component (widths of 27-43 mm for
10.5 mm leaves), so the default is not the setting to use on tillered plants.
Leaf length is not held to a tolerance: a leaf that touches another is measured
through both.
"""

import json
import logging

import pytest

from plantsim.evaluation import evaluate
from plantsim.evaluation import traits
from plantsim.scan.config import config_from_dict
from plantsim.scan.pipeline import run_scan
from plantsim.resources import bundled_plant_path

DENSE_SCAN = traits.TraitSettings(leaf_link_distance=0.003)
TOLERANCE = {"height_m": 0.02, "stem_diameter_m": 0.10, "mean_stem_distance_m": 0.10,
             "mean_nearest_stem_distance_m": 0.10, "leaf_width_m": 0.20}


@pytest.fixture(scope="module", params=["maize", "wheat"])
def comparison(request):
    name = request.param
    result = run_scan(config_from_dict({"plant": {"bundled": name}, "scan": {"step_deg": 0.5},
                                        "ideal": True}))
    points = result.cloud.plant_only().points_turntable
    truth = json.loads(evaluate.truth_traits_path(bundled_plant_path(name)).read_text())
    # The wheat file's mean_stem_distance_m is the nearest-neighbour mean: the
    # warning about it is expected here and not the subject of this test.
    logger = logging.getLogger("plantsim.evaluation.traits")
    level = logger.level
    logger.setLevel(logging.ERROR)
    try:
        reference = traits.traits_from_truth(evaluate.truth_in_turntable(truth, result.plant.T_turntable_mesh))
    finally:
        logger.setLevel(level)
    estimate = traits.extract_traits(points, settings=DENSE_SCAN)
    return name, traits.compare_traits(estimate, reference)


def test_every_stem_is_found_and_placed(comparison):
    name, c = comparison
    assert c.n_stems[0] == c.n_stems[1] == {"maize": 1, "wheat": 4}[name]
    offsets = [e.absolute_error for e in c.errors if e.trait.endswith("center_offset_m")]
    assert len(offsets) == c.n_stems[1] and max(offsets) < 0.001


@pytest.mark.parametrize("trait", list(TOLERANCE))
def test_trait_within_its_tolerance(comparison, trait):
    name, c = comparison
    if name == "maize" and "stem_distance" in trait:
        pytest.skip("one stem: no distance between stems")
    error = c[trait]
    assert error.relative_error <= TOLERANCE[trait], (
        f"{name} {trait}: S = {error.estimate:.5g} m, R = {error.reference:.5g} m, "
        f"error {error.relative_error:.1%} > {TOLERANCE[trait]:.0%}")


def test_each_stem_diameter_within_ten_percent(comparison):
    _, c = comparison
    per_stem = [e for e in c.errors if e.trait.startswith("stem[") and e.trait.endswith("diameter_m")]
    assert per_stem and all(e.relative_error <= 0.10 for e in per_stem)
