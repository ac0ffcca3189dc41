"""Robot data: the derived A1 URDF matches the official description; robot.toml is validated."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet_data
import pytest

from robots import CANONICAL_JOINTS, UnknownNameError, available_robots, load_robot

OFFICIAL_A1 = Path(pybullet_data.getDataPath()) / "a1" / "a1.urdf"


def _masses(path: Path) -> dict[str, float]:
    root = ET.parse(path).getroot()
    return {link.get("name"): float(link.find("inertial/mass").get("value"))
            for link in root.findall("link") if link.find("inertial/mass") is not None}


def _joints(path: Path) -> dict[str, ET.Element]:
    return {j.get("name"): j for j in ET.parse(path).getroot().findall("joint")}


def _xyz(elem: ET.Element | None) -> np.ndarray:
    return np.array([float(v) for v in elem.get("xyz").split()]) if elem is not None else np.zeros(3)


def test_a1_total_and_link_masses_match_official():
    ours, official = _masses(load_robot("a1").urdf), _masses(OFFICIAL_A1)
    assert sum(ours.values()) == pytest.approx(sum(official.values()), rel=0.01)
    for link, mass in ours.items():
        assert mass == pytest.approx(official[link], rel=0.01), link


def test_a1_joint_origins_axes_and_limits_match_official():
    ours, official = _joints(load_robot("a1").urdf), _joints(OFFICIAL_A1)
    movable = [name for name, j in official.items() if j.get("type") == "revolute"]
    assert sorted(movable) == sorted(load_robot("a1").joints)
    for name, joint in ours.items():
        ref = official[name]
        np.testing.assert_allclose(_xyz(joint.find("origin")), _xyz(ref.find("origin")), rtol=0.01, atol=1e-9)
        if joint.get("type") == "revolute":
            np.testing.assert_allclose(_xyz(joint.find("axis")), _xyz(ref.find("axis")), atol=1e-9)
            for key in ("lower", "upper", "effort", "velocity"):
                assert float(joint.find("limit").get(key)) == pytest.approx(float(ref.find("limit").get(key)), rel=0.01)


@pytest.mark.parametrize("name", available_robots())
def test_robot_data_is_consistent(name):
    robot = load_robot(name)
    assert len(robot.joints) == len(CANONICAL_JOINTS) == robot.default_pose.size
    links = {link.get("name") for link in ET.parse(robot.urdf).getroot().findall("link")}
    assert robot.base_link in links and set(robot.foot_links) <= links
    assert set(robot.fall.contact_links) <= links
    assert set(robot.joints) <= set(_joints(robot.urdf))
    # Legs are named in canonical order FR, FL, RR, RL for joints and feet alike.
    sides = [("R", "F"), ("L", "F"), ("R", "R"), ("L", "R")]
    positions = _foot_positions(robot.urdf, robot.foot_links)
    for (side, end), pos in zip(sides, positions):
        assert (pos[1] < 0) == (side == "R") and (pos[0] > 0) == (end == "F")


def _foot_positions(urdf: Path, feet: tuple[str, ...]) -> list[np.ndarray]:
    """Foot positions at the zero pose (frames are aligned with the base in derived URDFs)."""
    joints = ET.parse(urdf).getroot().findall("joint")
    parent_of = {j.find("child").get("link"): (j.find("parent").get("link"), _xyz(j.find("origin"))) for j in joints}
    out = []
    for foot in feet:
        pos, link = np.zeros(3), foot
        while link in parent_of:
            link, offset = parent_of[link]
            pos = pos + offset
        out.append(pos)
    return out


def test_anymal_mass_is_that_of_the_official_description():
    assert sum(_masses(load_robot("anymal").urdf).values()) == pytest.approx(52.13, abs=0.05)


def test_unknown_robot_lists_valid_names():
    with pytest.raises(UnknownNameError, match="unknown robot 'spot'; valid: a1, anymal"):
        load_robot("spot")
