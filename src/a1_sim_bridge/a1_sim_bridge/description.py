"""The robot's URDF for /robot_description (library core, no ROS): the file the simulation loads
(pybullet_data's a1/a1.urdf), so its joint names are the ones /joint_states carries.

Two changes make it usable by robot_state_publisher and RViz anywhere: meshes as absolute
``file://`` URIs, and a ``base_link`` root. base_link is the frame the stack's state lives in
(REP-105: /odom's child frame): PyBullet's base frame, at the trunk's centre of mass, so the URDF's
``trunk`` hangs from it by minus the trunk's inertial origin.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import pybullet_data
from a1_interface.contract import BASE_FRAME

ROBOT_URDF = Path(pybullet_data.getDataPath()) / "a1" / "a1.urdf"


def robot_description(urdf: Path = ROBOT_URDF) -> str:
    root = ET.parse(urdf).getroot()
    for mesh in root.iter("mesh"):
        mesh.set("filename", (urdf.parent / mesh.get("filename", "")).resolve().as_uri())
    trunk_origin = root.find("link[@name='trunk']/inertial/origin")
    com = [float(v) for v in trunk_origin.get("xyz", "0 0 0").split()] if trunk_origin is not None else [0.0] * 3
    base = ET.Element("link", name=BASE_FRAME)
    joint = ET.Element("joint", name=f"{BASE_FRAME}_to_trunk", type="fixed")
    ET.SubElement(joint, "parent", link=BASE_FRAME)
    ET.SubElement(joint, "child", link="trunk")
    ET.SubElement(joint, "origin", xyz=" ".join(f"{-v:.6g}" for v in com), rpy="0 0 0")
    root.insert(0, joint)
    root.insert(0, base)
    return ET.tostring(root, encoding="unicode")
