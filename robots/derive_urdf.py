"""Derive a compact, frame-aligned URDF from an official robot description.

The official descriptions carry dozens of fixed links (cameras, shells, drive housings),
rotated intermediate frames and mesh visuals. Every engine is happier with one link per
moving part, frames parallel to the base at the zero pose, and primitive shapes. This tool
lumps each rigid group (links joined by fixed joints) into one link, keeps the total mass,
centre of mass and inertia of the group exactly, rotates joint axes into the base frame and
re-expresses the collision primitives, which double as visuals.

    python -m robots.derive_urdf OFFICIAL.urdf OUT.urdf --name a1 --feet FR_toe FL_toe RR_toe RL_toe

It is run once by a maintainer; the output is committed. Feet stay links of their own so
every engine can report foot contacts by link.
"""

from __future__ import annotations

import argparse
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

import numpy as np


def _vec(text: str | None, default: float = 0.0) -> np.ndarray:
    return np.array([float(v) for v in text.split()]) if text else np.full(3, default)


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


def matrix_to_rpy(m: np.ndarray) -> np.ndarray:
    pitch = np.arcsin(-np.clip(m[2, 0], -1.0, 1.0))
    if abs(np.cos(pitch)) > 1e-9:
        return np.array([np.arctan2(m[2, 1], m[2, 2]), pitch, np.arctan2(m[1, 0], m[0, 0])])
    return np.array([np.arctan2(-m[1, 2], m[1, 1]), pitch, 0.0])


def _pose(elem: ET.Element | None) -> tuple[np.ndarray, np.ndarray]:
    if elem is None:
        return np.eye(3), np.zeros(3)
    return rpy_to_matrix(_vec(elem.get("rpy"))), _vec(elem.get("xyz"))


POINT_MASS_KG = 0.005
MIN_SHAPE_M = 0.005


def _is_placeholder(geometry: ET.Element) -> bool:
    """True for millimetre marker shapes (IMU boxes) that are not part of the body."""
    shape = geometry[0]
    sizes = [float(v) for k, v in shape.attrib.items() if k in ("size", "radius", "length") for v in v.split()]
    return shape.tag != "mesh" and max(sizes) < MIN_SHAPE_M


@dataclass
class Group:
    """A rigid set of official links that becomes one derived link."""

    name: str
    origin: np.ndarray  # world position of the group frame at the zero pose
    members: list[str] = field(default_factory=list)


def _fmt(values: np.ndarray) -> str:
    return " ".join(f"{0.0 if abs(v) < 1e-12 else v:.9g}" for v in values)


def derive(src: str, name: str, feet: list[str], limits: tuple[float, float] | None = None) -> ET.Element:
    root = ET.parse(src).getroot()
    links = {link.get("name"): link for link in root.findall("link")}
    joints = root.findall("joint")
    child_of = {j.find("child").get("link"): j for j in joints}
    base = next(n for n in links if n not in child_of)

    world: dict[str, tuple[np.ndarray, np.ndarray]] = {base: (np.eye(3), np.zeros(3))}
    pending = list(joints)
    while pending:
        for joint in list(pending):
            parent = joint.find("parent").get("link")
            if parent in world:
                rp, pp = world[parent]
                rj, pj = _pose(joint.find("origin"))
                world[joint.find("child").get("link")] = (rp @ rj, pp + rp @ pj)
                pending.remove(joint)

    def starts_group(link: str) -> bool:
        joint = child_of.get(link)
        return joint is None or joint.get("type") != "fixed" or link in feet

    group_of: dict[str, Group] = {}
    groups: list[Group] = []
    order = [base] + [j.find("child").get("link") for j in joints]
    for link in order:
        if starts_group(link):
            group = Group(link, world[link][1])
            groups.append(group)
        else:
            group = group_of[child_of[link].find("parent").get("link")]
        group.members.append(link)
        group_of[link] = group

    robot = ET.Element("robot", name=name)
    for group in groups:
        robot.append(_derived_link(group, links, world))
    for group in groups[1:]:
        official = child_of[group.name]
        parent = group_of[official.find("parent").get("link")]
        joint = ET.SubElement(robot, "joint", name=official.get("name"), type=official.get("type"))
        ET.SubElement(joint, "parent", link=parent.name)
        ET.SubElement(joint, "child", link=group.name)
        ET.SubElement(joint, "origin", xyz=_fmt(group.origin - parent.origin), rpy="0 0 0")
        if official.get("type") != "fixed":
            axis_local = _vec(official.find("axis").get("xyz") if official.find("axis") is not None else "1 0 0")
            axis = world[group.name][0] @ axis_local
            ET.SubElement(joint, "axis", xyz=_fmt(np.round(axis, 9)))
            limit = official.find("limit")
            attrib = dict(limit.attrib) if limit is not None else {}
            if limits is not None and "lower" not in attrib:
                attrib.update(lower=str(limits[0]), upper=str(limits[1]))
            ET.SubElement(joint, "limit", **attrib)
    ET.indent(robot)
    return robot


def _derived_link(group: Group, links: dict, world: dict) -> ET.Element:
    masses, coms, inertias, shapes = [], [], [], []
    for member in group.members:
        rot, pos = world[member]
        link = links[member]
        inertial = link.find("inertial")
        if inertial is not None and inertial.find("mass") is not None:
            r_com, p_com = _pose(inertial.find("origin"))
            i = inertial.find("inertia")
            ixx, iyy, izz, ixy, ixz, iyz = (float(i.get(k, 0.0)) for k in ("ixx", "iyy", "izz", "ixy", "ixz", "iyz"))
            local = np.array([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
            r = rot @ r_com
            mass = float(inertial.find("mass").get("value"))
            masses.append(mass)
            coms.append(pos + rot @ p_com)
            # Gram-scale placeholder links carry made-up inertias: keep them as point masses.
            inertias.append(r @ local @ r.T if mass >= POINT_MASS_KG else np.zeros((3, 3)))
        for collision in link.findall("collision"):
            if _is_placeholder(collision.find("geometry")):
                continue
            r_geom, p_geom = _pose(collision.find("origin"))
            shapes.append((rot @ r_geom, pos + rot @ p_geom - group.origin, collision.find("geometry")))

    out = ET.Element("link", name=group.name)
    if masses:
        m = np.array(masses)
        com = (m[:, None] * np.array(coms)).sum(0) / m.sum()
        inertia = np.zeros((3, 3))
        for mi, ci, ii in zip(masses, coms, inertias):
            d = ci - com
            inertia += ii + mi * (d @ d * np.eye(3) - np.outer(d, d))
        inertial = ET.SubElement(out, "inertial")
        ET.SubElement(inertial, "origin", xyz=_fmt(com - group.origin), rpy="0 0 0")
        ET.SubElement(inertial, "mass", value=f"{m.sum():.9g}")
        ET.SubElement(inertial, "inertia", ixx=f"{inertia[0, 0]:.9g}", iyy=f"{inertia[1, 1]:.9g}",
                      izz=f"{inertia[2, 2]:.9g}", ixy=f"{inertia[0, 1]:.9g}", ixz=f"{inertia[0, 2]:.9g}",
                      iyz=f"{inertia[1, 2]:.9g}")
    for tag in ("visual", "collision"):
        for rot, pos, geometry in shapes:
            elem = ET.SubElement(out, tag)
            ET.SubElement(elem, "origin", xyz=_fmt(pos), rpy=_fmt(matrix_to_rpy(rot)))
            elem.append(geometry)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("src", help="official URDF")
    parser.add_argument("out", help="derived URDF to write")
    parser.add_argument("--name", required=True, help="robot name in the derived URDF")
    parser.add_argument("--feet", nargs="+", required=True, help="official foot links, kept as links")
    parser.add_argument("--limits", nargs=2, type=float, metavar=("LOWER", "UPPER"),
                        help="position limits (rad) for joints whose official description has none")
    parser.add_argument("--header", default="", help="comment placed at the top of the output")
    args = parser.parse_args()
    robot = derive(args.src, args.name, args.feet, args.limits)
    text = ET.tostring(robot, encoding="unicode")
    with open(args.out, "w") as f:
        f.write('<?xml version="1.0"?>\n')
        if args.header:
            f.write(f"<!-- {args.header} -->\n")
        f.write(text + "\n")


if __name__ == "__main__":
    main()
