"""Habitat navmeshes (Recast/Detour tile sets) read into NumPy.

A ReplicaCAD ``navmeshes/<scene>.navmesh`` is what habitat-sim's
``PathFinder.save_nav_mesh`` writes: a ``MSET`` set header (version 1 without,
version 2 with habitat's 56-byte ``NavMeshSettings`` block), then per tile a
``(tile ref, data size)`` pair and a Detour tile (``DNAV``, version 7). Only
what the loader needs is read: polygon vertices, polygons and which polygon
edges are borders (Detour neighbour code 0: no polygon on the other side).

Coordinates are returned in Drake's Z-up world: the conversion is
``vamg_drake.world.replicacad.points_to_z_up`` (the one place where Y-up
becomes Z-up), passed in by the caller so this module has no frame convention
of its own.
"""

import struct
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from vamg_drake.world.primitives import points_in_polygon

_SET_MAGIC = int.from_bytes(b"MSET", "big")
_TILE_MAGIC = int.from_bytes(b"DNAV", "big")
_TILE_VERSION = 7
_VERTS_PER_POLY = 6
_POLY_SIZE = 32  # dtPoly: firstLink u32, verts u16[6], neis u16[6], flags u16, vertCount u8, areaAndtype u8
_TILE_HEADER = struct.Struct("<iiiiiIiiiiiiiiiffffffffff")  # dtMeshHeader, 100 bytes
_PARAMS = struct.Struct("<fffffii")  # dtNavMeshParams, 28 bytes
_HABITAT_SETTINGS_SIZE = 56  # NavMeshSettings: 13 floats + 3 bools (+ padding)
_EXTERNAL_LINK = 0x8000


class NavMeshError(ValueError):
    """A navmesh file is missing or not a Detour tile set this reader understands."""


@dataclass(frozen=True)
class NavMesh:
    """The walkable floor of a scene, in W (z up).

    Attributes:
        source: the file it was read from.
        vertices: (V, 3) polygon vertices.
        polygons: convex polygons as vertex-index arrays (3..6 each).
        boundary_edges: (E, 2, 3) polygon edges with no walkable neighbour.
        agent_radius: the radius the walkable area was eroded by [m].
        agent_height: [m].
    """

    source: Path
    vertices: np.ndarray
    polygons: tuple[np.ndarray, ...]
    boundary_edges: np.ndarray
    agent_radius: float
    agent_height: float

    def polygon_xy(self, i: int) -> np.ndarray:
        """Returns polygon ``i`` as a (k, 2) array in the plane."""
        return self.vertices[self.polygons[i], :2]

    def contains_xy(self, points: np.ndarray) -> np.ndarray:
        """Whether (N, 2) points lie on a walkable polygon (projected onto the plane)."""
        points = np.atleast_2d(np.asarray(points, dtype=float))
        inside = np.zeros(len(points), dtype=bool)
        for i in range(len(self.polygons)):
            poly = self.polygon_xy(i)
            lo, hi = poly.min(axis=0), poly.max(axis=0)
            near = ~inside & np.all((points >= lo - 1e-9) & (points <= hi + 1e-9), axis=1)
            if np.any(near):
                inside[near] = points_in_polygon(points[near], poly)
        return inside

    def bounds(self) -> np.ndarray:
        """Returns (2, 3) [lower, upper] corners of the vertices."""
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)])


def read_navmesh(
    path: Path, to_z_up: Callable[[np.ndarray], np.ndarray], floor_tolerance: float = 0.3
) -> NavMesh:
    """Reads a habitat navmesh file, keeping the floor level only.

    Habitat navmeshes also cover walkable tops of furniture (beds, tables) that
    no wheeled base reaches; only polygons whose mean height is within
    ``floor_tolerance`` of the area-weighted median polygon height are kept,
    and an edge shared with a dropped polygon becomes a boundary edge.

    Args:
        path: the ``.navmesh`` file.
        to_z_up: maps (N, 3) Y-up points to Z-up.
        floor_tolerance: [m].

    Raises:
        NavMeshError: naming the file, if it is missing or malformed.
    """
    path = Path(path)
    if not path.is_file():
        raise NavMeshError(f"{path}: navmesh file not found")
    data = path.read_bytes()
    try:
        return _parse(path, data, to_z_up, floor_tolerance)
    except (struct.error, IndexError, ValueError) as e:
        if isinstance(e, NavMeshError):
            raise
        raise NavMeshError(f"{path}: truncated or malformed navmesh ({e})") from e


def _parse(path: Path, data: bytes, to_z_up, floor_tolerance: float) -> NavMesh:
    magic, version, num_tiles = struct.unpack_from("<iii", data, 0)
    if magic != _SET_MAGIC:
        raise NavMeshError(f"{path}: not a Detour navmesh set (magic {magic:#x})")
    if version not in (1, 2):
        raise NavMeshError(f"{path}: unsupported navmesh set version {version}")
    offset = 12 + _PARAMS.size + (_HABITAT_SETTINGS_SIZE if version == 2 else 0)
    vertices: list[np.ndarray] = []
    polygons: list[np.ndarray] = []  # global vertex indices
    neighbours: list[np.ndarray] = []  # global polygon index per edge, -1 border, -2 other tile
    agent_radius = agent_height = 0.0
    vertex_base = poly_base = 0
    for _ in range(num_tiles):
        _tile_ref, size = struct.unpack_from("<Ii", data, offset)
        offset += 8
        if size <= 0:
            continue
        tile = data[offset : offset + size]
        offset += size
        header = _TILE_HEADER.unpack_from(tile, 0)
        if header[0] != _TILE_MAGIC or header[1] != _TILE_VERSION:
            raise NavMeshError(f"{path}: tile is not a Detour v{_TILE_VERSION} tile")
        poly_count, vert_count = header[6], header[7]
        agent_height, agent_radius = header[15], header[16]
        p = _TILE_HEADER.size
        vertices.append(np.frombuffer(tile, dtype="<f4", count=3 * vert_count, offset=p).reshape(-1, 3).astype(float))
        p += 12 * vert_count
        for k in range(poly_count):
            raw = tile[p + k * _POLY_SIZE : p + (k + 1) * _POLY_SIZE]
            idx = np.frombuffer(raw, dtype="<u2", count=_VERTS_PER_POLY, offset=4)
            neis = np.frombuffer(raw, dtype="<u2", count=_VERTS_PER_POLY, offset=16)
            n = raw[30]
            if not 3 <= n <= _VERTS_PER_POLY:
                raise NavMeshError(f"{path}: polygon {k} has {n} vertices")
            nb = np.where(neis[:n] == 0, -1, np.where(neis[:n] & _EXTERNAL_LINK, -2, neis[:n].astype(np.int64) - 1 + poly_base))
            if (raw[31] >> 6) != 0:  # an off-mesh connection, not a floor polygon
                nb = np.full(n, -3)
            polygons.append(idx[:n].astype(np.int64) + vertex_base)
            neighbours.append(nb)
        vertex_base += vert_count
        poly_base += poly_count
    if not polygons:
        raise NavMeshError(f"{path}: navmesh has no polygons")
    V = to_z_up(np.concatenate(vertices))
    height = np.array([V[poly, 2].mean() for poly in polygons])
    area = np.array([abs(_area(V[poly, :2])) for poly in polygons])
    order = np.argsort(height)
    cumulative = np.cumsum(area[order])
    floor = float(height[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])
    keep = (np.abs(height - floor) <= floor_tolerance) & np.array([nb[0] != -3 for nb in neighbours])
    edges = []
    for i in np.flatnonzero(keep):
        poly, nb = polygons[i], neighbours[i]
        for j in range(len(poly)):
            if nb[j] == -1 or (nb[j] >= 0 and not keep[nb[j]]):
                edges.append(V[[poly[j], poly[(j + 1) % len(poly)]]])
    kept = tuple(polygons[i] for i in np.flatnonzero(keep))
    E = np.asarray(edges, dtype=float).reshape(-1, 2, 3)
    return NavMesh(path, V, kept, E, float(agent_radius), float(agent_height))


def _area(poly: np.ndarray) -> float:
    x, y = poly[:, 0], poly[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
