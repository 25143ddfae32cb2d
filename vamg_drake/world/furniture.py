"""Furniture made of primitives: tables, counters, shelves, chairs, sofas, cabinets.

Every builder returns a ``Furniture`` in its own frame F: origin on the floor at
the centre of the footprint, +x along the length, +y towards the back (the
wall, for pieces that stand against one), z up. The front, where a robot
approaches, is the -y side. Only the topmost horizontal face of each footprint
is a support surface (the paper keeps "only the topmost surface for each
horizontal footprint"), so a shelf's lower boards are obstacles, not supports.
"""

from __future__ import annotations

import numpy as np

from vamg_drake.world.scenario import Box, Cylinder, Furniture, Part, PlanarPose

_WOOD = [0.55, 0.40, 0.26, 1.0]
_DARK_WOOD = [0.35, 0.24, 0.16, 1.0]
_WHITE = [0.90, 0.90, 0.87, 1.0]
_STONE = [0.62, 0.62, 0.60, 1.0]
_FABRIC = [0.30, 0.38, 0.50, 1.0]
_METAL = [0.45, 0.45, 0.48, 1.0]

#: Kinds that stand with their back against a wall.
AGAINST_WALL = ("counter", "shelf", "sofa", "cabinet")


def _furniture(name: str, kind: str, parts: list[Part]) -> Furniture:
    """Returns the furniture with dimensions rounded to 1e-5 m (exact, readable YAML)."""
    for part in parts:
        part.xyz = [round(float(v), 5) for v in part.xyz]
        if isinstance(part.shape, Box):
            part.shape.size = [round(float(v), 5) for v in part.shape.size]
        else:
            part.shape.radius = round(float(part.shape.radius), 5)
            part.shape.length = round(float(part.shape.length), 5)
    return Furniture(name=name, kind=kind, parts=parts)


def _box(name, size, xyz, rgba, support=False) -> Part:
    return Part(name=name, shape=Box([float(s) for s in size]), xyz=[float(v) for v in xyz], support=support, rgba=list(rgba))


def table(name: str, length: float, width: float, height: float, round_top: bool = False) -> Furniture:
    """A table: a top slab (support) on four legs, or a round top on a pedestal."""
    t = 0.04
    if round_top:
        radius = 0.5 * min(length, width)
        parts = [
            Part(name="top", shape=Cylinder(radius, t), xyz=[0.0, 0.0, height - 0.5 * t], support=True, rgba=list(_WOOD)),
            Part(name="pedestal", shape=Cylinder(0.06, height - t), xyz=[0.0, 0.0, 0.5 * (height - t)], rgba=list(_METAL)),
            Part(name="foot", shape=Cylinder(0.3 * radius + 0.1, 0.03), xyz=[0.0, 0.0, 0.015], rgba=list(_METAL)),
        ]
        return _furniture(name, "table", parts)
    leg = 0.05
    parts = [_box("top", [length, width, t], [0, 0, height - 0.5 * t], _WOOD, support=True)]
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        x = sx * (0.5 * length - leg)
        y = sy * (0.5 * width - leg)
        parts.append(_box(f"leg_{i}", [leg, leg, height - t], [x, y, 0.5 * (height - t)], _DARK_WOOD))
    return _furniture(name, "table", parts)


def counter(name: str, length: float, depth: float, height: float) -> Furniture:
    """A kitchen counter: a cabinet body with a stone top slab (support) overhanging the front."""
    t = 0.04
    overhang = 0.03
    return _furniture(
        name,
        "counter",
        [
            _box("body", [length, depth - overhang, height - t], [0, 0.5 * overhang, 0.5 * (height - t)], _WHITE),
            _box("top", [length, depth, t], [0, 0, height - 0.5 * t], _STONE, support=True),
        ],
    )


def cabinet(name: str, length: float, depth: float, height: float) -> Furniture:
    """A closed cabinet (sideboard, dresser) whose top is a support."""
    t = 0.03
    return _furniture(
        name,
        "cabinet",
        [
            _box("body", [length, depth, height - t], [0, 0, 0.5 * (height - t)], _DARK_WOOD),
            _box("top", [length, depth, t], [0, 0, height - 0.5 * t], _WOOD, support=True),
        ],
    )


def shelf(name: str, length: float, depth: float, height: float, levels: int) -> Furniture:
    """An open shelf: side panels, a back panel and ``levels`` boards; the top board is the support."""
    if levels < 2:
        raise ValueError(f"shelf {name!r}: levels must be >= 2, got {levels}")
    t = 0.025
    parts = [
        _box("side_left", [t, depth, height], [-0.5 * (length - t), 0, 0.5 * height], _WOOD),
        _box("side_right", [t, depth, height], [0.5 * (length - t), 0, 0.5 * height], _WOOD),
        _box("back", [length - 2 * t, t, height - t], [0, 0.5 * (depth - t), 0.5 * (height - t)], _DARK_WOOD),
    ]
    for k in range(levels):
        z_top = 0.05 + (height - 0.05) * k / (levels - 1)
        is_top = k == levels - 1
        width = length if is_top else length - 2 * t
        parts.append(_box("top" if is_top else f"board_{k}", [width, depth, t], [0, 0, z_top - 0.5 * t], _WOOD, support=is_top))
    return _furniture(name, "shelf", parts)


def chair(name: str, seat: float = 0.45, seat_height: float = 0.45, back_height: float = 0.9) -> Furniture:
    """A chair: seat, four legs and a back rest at +y."""
    leg = 0.04
    t = 0.04
    parts = [_box("seat", [seat, seat, t], [0, 0, seat_height - 0.5 * t], _WOOD)]
    for i, (sx, sy) in enumerate([(-1, -1), (1, -1), (1, 1), (-1, 1)]):
        parts.append(_box(f"leg_{i}", [leg, leg, seat_height - t], [sx * (0.5 * seat - leg), sy * (0.5 * seat - leg), 0.5 * (seat_height - t)], _DARK_WOOD))
    rest = back_height - seat_height
    parts.append(_box("back", [seat, t, rest], [0, 0.5 * (seat - t), seat_height + 0.5 * rest], _WOOD))
    return _furniture(name, "chair", parts)


def sofa(name: str, length: float, depth: float = 0.85) -> Furniture:
    """A sofa: base, seat cushion, back (at +y) and two arms."""
    arm = 0.18
    back = 0.2
    return _furniture(
        name,
        "sofa",
        [
            _box("base", [length, depth, 0.25], [0, 0, 0.125], _FABRIC),
            _box("cushion", [length - 2 * arm, depth - back, 0.17], [0, -0.5 * back, 0.335], _FABRIC),
            _box("back", [length, back, 0.55], [0, 0.5 * (depth - back), 0.525], _FABRIC),
            _box("arm_left", [arm, depth - back, 0.35], [-0.5 * (length - arm), -0.5 * back, 0.425], _FABRIC),
            _box("arm_right", [arm, depth - back, 0.35], [0.5 * (length - arm), -0.5 * back, 0.425], _FABRIC),
        ],
    )


def sample_furniture(kind: str, name: str, rng: np.random.Generator) -> Furniture:
    """Returns a piece of ``kind`` with dimensions drawn from ``rng``, at the origin."""
    u = rng.uniform
    if kind == "table":
        if u() < 0.25:
            d = u(0.8, 1.2)
            return table(name, d, d, u(0.70, 0.76), round_top=True)
        return table(name, u(0.9, 1.6), u(0.6, 0.9), u(0.70, 0.78))
    if kind == "counter":
        return counter(name, u(1.2, 2.4), u(0.55, 0.65), u(0.86, 0.94))
    if kind == "cabinet":
        return cabinet(name, u(0.6, 1.2), u(0.40, 0.55), u(0.55, 1.0))
    if kind == "shelf":
        tall = u() < 0.4
        height = u(1.5, 1.9) if tall else u(0.8, 1.15)
        levels = int(rng.integers(4, 6)) if tall else int(rng.integers(2, 4))
        return shelf(name, u(0.7, 1.2), u(0.30, 0.42), height, levels)
    if kind == "chair":
        return chair(name, u(0.42, 0.50), u(0.43, 0.48), u(0.85, 1.0))
    if kind == "sofa":
        return sofa(name, u(1.5, 2.2), u(0.8, 0.95))
    raise ValueError(f"unknown furniture kind {kind!r}")


def footprint_size(furniture: Furniture) -> np.ndarray:
    """Returns the (2,) size of the axis-aligned footprint rectangle in F (x, y), centred on F."""
    probe = Furniture(name=furniture.name, kind=furniture.kind, pose=PlanarPose(), parts=furniture.parts)
    corners = np.concatenate([p.footprint() for p in probe.primitives()])
    return 2.0 * np.max(np.abs(corners), axis=0)
