"""The one path from a cell to its results: settings checked once, a robot from any folder."""

from __future__ import annotations

import shutil

import pytest

from benchmark.trial.cell import CellSpec, make_cell
from benchmark.trial.trials import run_cell
from benchmark.common.settings import SettingError
from robots import ROBOTS_DIR, load_robot


def test_a_robot_from_a_folder_outside_the_package_walks(tmp_path):
    folder = tmp_path / "my_a1"
    shutil.copytree(ROBOTS_DIR / "a1", folder)
    toml = folder / "robot.toml"
    toml.write_text(toml.read_text().replace('name = "a1"', 'name = "my_a1"'))
    robot = load_robot(str(folder))
    assert robot.name == "my_a1" and robot.folder == folder
    result = run_cell(make_cell({"robot": str(folder), "policy": "rl", "duration": 3.0}), [0])[0]
    assert result.distance_m > 2.0 and result.fall_time is None


@pytest.mark.parametrize("values, message", [
    ({"policy": "rl", "history": 10}, "'history' does not apply to policy 'rl'"),
    ({"sim": "pybullet", "device": "cpu"}, "'device' does not apply to simulator 'pybullet'"),
    ({"history": "abc"}, "setting 'history' expects an integer, got 'abc'"),
    ({"constrained": "maybe"}, "setting 'constrained' expects a boolean"),
    ({"history": -1}, "history must be >= 0"),
    ({"colour": "red"}, "unknown setting 'colour'; valid: sim, robot"),
])
def test_bad_settings_are_one_line(values, message):
    with pytest.raises(SettingError) as err:
        make_cell(values)
    assert message in str(err.value) and "\n" not in str(err.value)


def test_settings_of_another_policy_are_dropped_in_grids_and_defaults_come_from_the_policy():
    cell = make_cell({"policy": "rl", "history": 10, "encoding": "E3"}, strict=False)
    assert cell.settings.policy_file is None and "history" not in cell.params()
    assert CellSpec(policy="llm").duration == 20.0 and CellSpec(policy="rl").duration == 10.0
    assert make_cell({"sim": "newton"}).engine_options == {"device": None, "solver": "mujoco", "contacts": "newton"}
