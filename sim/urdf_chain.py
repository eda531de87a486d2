"""Reading a URDF as an arm: the seven revolute joints from the root to the flange, checked.

:func:`read_urdf` drops every ``<visual>`` and ``<collision>`` (meshes are neither needed
nor looked for), finds the flange (named, or the one leaf below the last movable joint),
checks that the joints before it form one serial chain of seven revolute joints whose bodies
all have an inertial with a mass, makes ``continuous`` joints revolute within ±π, and leaves
out what hangs beyond the flange (:mod:`sim.description` keeps the Panda's hand). Every
problem is an :class:`iem.errors.InvalidInputError` naming it.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET

from iem.errors import InvalidInputError
from iem.types import N_JOINTS

MOVABLE = ("revolute", "continuous", "prismatic", "floating", "planar")
"""URDF joint types that move."""


def arm_error(source: str, what: str) -> InvalidInputError:
    return InvalidInputError(f"arm model {source}: {what}")


def parse(text: str, source: str) -> ET.Element:
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise arm_error(source, f"not readable XML: {exc}") from exc
    return root


def _prefixed(root: ET.Element, prefix: str) -> None:
    for el in root.iter():
        if el.tag in ("link", "joint") and el.get("name"):
            el.set("name", prefix + el.get("name"))
        if el.tag in ("parent", "child") and el.get("link"):
            el.set("link", prefix + el.get("link"))


def _tree(root: ET.Element, source: str):
    links = {el.get("name"): el for el in root.findall("link")}
    joints = root.findall("joint")
    parent_of: dict[str, ET.Element] = {}
    for j in joints:
        child = j.find("child")
        if child is None or j.find("parent") is None:
            raise arm_error(source, f"joint {j.get('name')!r} lacks a parent or a child link")
        name = child.get("link")
        if name in parent_of:
            raise arm_error(source, f"link {name!r} has two parent joints ("
                         f"{parent_of[name].get('name')!r}, {j.get('name')!r}): the "
                         "description is not a tree")
        parent_of[name] = j
    roots = [n for n in links if n not in parent_of]
    if len(roots) != 1:
        raise arm_error(source, f"the description must have one root link, it has {roots}")
    return links, joints, parent_of, roots[0]


def _subtree(start: str, joints) -> set[str]:
    """The links at and below ``start``."""
    children: dict[str, list[str]] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j.find("child").get("link"))
    out, todo = set(), [start]
    while todo:
        n = todo.pop()
        out.add(n)
        todo.extend(children.get(n, []))
    return out


def _auto_flange(links, joints, parent_of, root: str, source: str) -> str:
    """The flange of a file that does not name one: below the last movable joint, the one
    leaf reached through fixed joints alone."""
    movable = [j for j in joints if j.get("type") in MOVABLE]
    children: dict[str, list[ET.Element]] = {}
    for j in joints:
        children.setdefault(j.find("parent").get("link"), []).append(j)
    # the movable joint with no movable joint below it
    last = [j for j in movable
            if not any(k.get("type") in MOVABLE for k in joints
                       if k is not j and k.find("parent").get("link")
                       in _subtree(j.find("child").get("link"), joints))]
    if len(last) != 1:
        raise arm_error(source, "no flange: the description names none and its movable joints "
                     f"end in {len(last)} places ({', '.join(j.get('name') for j in last)}); "
                     "name the flange link with [arm] flange (--arm-flange)")
    link = last[0].find("child").get("link")
    while children.get(link):
        below = children[link]
        if len(below) != 1:
            raise arm_error(source, f"no flange: link {link!r} below the last joint branches into "
                         f"{', '.join(c.find('child').get('link') for c in below)}; name the "
                         "flange link with [arm] flange (--arm-flange)")
        link = below[0].find("child").get("link")
    return link


def joint_limit(j: ET.Element, key: str, source: str) -> float | None:
    el = j.find("limit")
    if el is None or el.get(key) is None:
        return None
    try:
        return float(el.get(key))
    except ValueError as exc:
        raise arm_error(source, f"joint {j.get('name')!r}: limit {key} {el.get(key)!r} is not a "
                     "number") from exc


def read_urdf(text: str, source: str, flange: str | None, prefix: str):
    root = parse(text, source)
    if root.tag != "robot":
        raise arm_error(source, f"a URDF's root element is <robot>, this one's is <{root.tag}>")
    if prefix:
        _prefixed(root, prefix)
    for link in root.findall("link"):
        for tag in ("visual", "collision"):
            for el in link.findall(tag):
                link.remove(el)  # meshes are not needed (nor looked for)
    links, joints, parent_of, base = _tree(root, source)
    if flange is None:
        flange = _auto_flange(links, joints, parent_of, base, source)
    if flange not in links:
        raise arm_error(source, f"no flange: it has no link {flange!r}; its links are "
                     f"{', '.join(links)}")
    chain, link = [], flange
    while link in parent_of:
        chain.append(parent_of[link])
        link = parent_of[link].find("parent").get("link")
    chain.reverse()
    arm = [j for j in chain if j.get("type") in MOVABLE]
    kinds = {j.get("name"): j.get("type") for j in arm}
    if len(arm) != N_JOINTS or any(t not in ("revolute", "continuous") for t in kinds.values()):
        raise arm_error(source, f"the way from {base!r} to the flange {flange!r} moves "
                     f"{len(arm)} joints ({', '.join(f'{n}: {t}' for n, t in kinds.items())}); "
                     f"the plug-in supports arms of {N_JOINTS} revolute joints")
    beyond = _subtree(flange, joints)
    on_chain = {j.get("name") for j in chain}
    for j in joints:
        if (j.get("type") in MOVABLE and j.get("name") not in on_chain
                and j.find("child").get("link") not in beyond):
            raise arm_error(source, f"not a chain: the movable joint {j.get('name')!r} hangs off "
                         f"{j.find('parent').get('link')!r}, before the flange {flange!r}; the "
                         "plug-in supports one serial arm")
    bodies = tuple(j.find("child").get("link") for j in arm)
    for name in bodies:
        inertial = links[name].find("inertial")
        mass = None if inertial is None or inertial.find("mass") is None else \
            inertial.find("mass").get("value")
        if mass is None or not float(mass) > 0.0:
            raise arm_error(source, f"link {name!r}, which joint {parent_of[name].get('name')!r} "
                         "moves, has no <inertial> with a mass > 0; the dynamics need every "
                         "moving body's mass, centre of mass and inertia")
    for j in arm:
        if j.get("type") == "continuous":  # one turn either way: a 1-dof revolute joint
            j.set("type", "revolute")
            lim = j.find("limit")
            if lim is None:
                lim = ET.SubElement(j, "limit", effort="0", velocity="0")
            lim.set("lower", f"{-math.pi!r}")
            lim.set("upper", f"{math.pi!r}")
    locked = tuple(j.get("name") for j in joints
                   if j.get("type") in MOVABLE and j.get("name") not in on_chain)
    full_text = ET.tostring(root, encoding="unicode")
    for j in joints:
        if j.find("child").get("link") in beyond and j.find("child").get("link") != flange:
            root.remove(j)
    for name in beyond - {flange}:
        root.remove(links[name])
    return root, ET.tostring(root, encoding="unicode"), full_text, flange, arm, bodies, locked
