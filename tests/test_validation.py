"""Strict settings: each wrong type refused in one line naming the key."""

import pytest

from plantsim.evaluation.evaluate import EvaluationOptions
from plantsim.validation import (SettingTypeError, check_bool, check_choice, check_int,
                                 check_number, check_optional, check_path, check_str)


def test_bool_refuses_strings_and_numbers():
    assert check_bool("output", "plant_only", False) is False
    for bad in ("false", "true", 0, 1, None):
        with pytest.raises(SettingTypeError, match=r"^output\.plant_only must be true or false, got "):
            check_bool("output", "plant_only", bad)


def test_setting_type_error_is_also_a_value_error():
    with pytest.raises(ValueError, match="ideal must be true or false"):
        check_bool("", "ideal", "false")


def test_int_refuses_bools_floats_and_strings_and_checks_range():
    assert check_int("scan", "n", 3, minimum=1) == 3
    for bad in (True, 2.0, "2"):
        with pytest.raises(SettingTypeError, match=r"^scan\.n must be an integer, got "):
            check_int("scan", "n", bad)
    with pytest.raises(ValueError, match=r"^scan\.n must be >= 1, got 0$"):
        check_int("scan", "n", 0, minimum=1)


def test_number_refuses_strings_nan_and_out_of_range():
    assert check_number("rig", "height_m", 2, unit="m") == 2.0
    with pytest.raises(SettingTypeError, match=r"^rig\.height_m must be a number m, got '0.3'"):
        check_number("rig", "height_m", "0.3", unit="m")
    with pytest.raises(ValueError, match=r"^rig\.height_m must be finite, got nan$"):
        check_number("rig", "height_m", float("nan"))
    with pytest.raises(ValueError, match=r"^rig\.height_m must be > 0 m, got 0$"):
        check_number("rig", "height_m", 0, minimum=0, strict_minimum=True, unit="m")
    with pytest.raises(ValueError, match=r"must be <= 1, got 2"):
        check_number("rig", "f", 2, maximum=1)


def test_choice_str_path_optional():
    assert check_choice("plant", "up", "z", "xyz") == "z"
    with pytest.raises(ValueError, match=r"^plant\.up must be one of x, y, z, got 'w'$"):
        check_choice("plant", "up", "w", "xyz")
    with pytest.raises(SettingTypeError, match=r"^plant\.up must be a string, got 1 \(int\)$"):
        check_choice("plant", "up", 1, "xyz")
    with pytest.raises(SettingTypeError, match=r"^plant\.bundled must be a string"):
        check_str("plant", "bundled", ["maize"])
    with pytest.raises(SettingTypeError, match=r"^output\.raw must be a path"):
        check_path("output", "raw", 3)
    assert check_optional(check_path, "output", "raw", None) is None


def test_evaluation_options_refuse_string_bools():
    with pytest.raises(SettingTypeError, match=r"^evaluation\.traits must be true or false, got 'false'"):
        EvaluationOptions(traits="false")
    with pytest.raises(SettingTypeError, match="evaluation.trait_settings must be a TraitSettings"):
        EvaluationOptions(trait_settings={"base_z": 0})


def _hide(monkeypatch, missing):
    import importlib.util

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec",
                        lambda name, *a: None if name == missing else real(name, *a))


def test_study_without_matplotlib_stops_before_any_run(monkeypatch, capsys, tmp_path):
    from plantsim.cli.app import main

    _hide(monkeypatch, "matplotlib")
    code = main(["study", "--step-deg", "90", "-o", str(tmp_path / "s.csv")])
    err = capsys.readouterr().err
    assert code == 2
    assert err == ("plantsim: error: plantsim study's plot needs matplotlib: "
                   "pip install 'plantsim[plot]'\n")
    assert list(tmp_path.iterdir()) == []


def test_rig_ping_without_the_sdk_is_one_line(monkeypatch, capsys):
    from plantsim.cli.app import main

    _hide(monkeypatch, "dynamixel_sdk")
    code = main(["rig", "ping", "--port", "/dev/null"])
    err = capsys.readouterr().err
    assert code == 2
    assert err == ("plantsim: error: plantsim rig ping needs dynamixel_sdk: "
                   "pip install 'plantsim[rig]'\n")
