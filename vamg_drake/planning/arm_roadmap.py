"""A roadmap of the torso + arm's self-collision-free space around a carry pose.

Folding the arm from an arbitrary configuration into the travel pose (and
unfolding it at the goal) is where straight joint-space interpolation fails
most: the line passes through the robot's own body. Self-collision does not
depend on the base pose or the map, so the free space of those motions can
be searched once per robot model: `ArmRoadmap` is a probabilistic roadmap
(Kavraki et al. 1996) over x = torso + 7 arm joints (8,) whose nodes and
straight edges are free of self-collision and inside the joint limits (the
checker's self-collision padding included), with node 0 the carry pose and the
shortest-path tree toward it precomputed. A query (`to_carry`) connects a
configuration to the cheapest roadmap node it reaches by a self-free straight
motion and follows the tree: a few compiled motion checks, no search.

The environment is not part of the roadmap: the caller checks the returned
motion (synchronized with the base) against the map like any other.

Edge lengths are the checker's sphere-displacement bound (metres of sphere
travel). Continuous joints: nodes are sampled in one turn and edges join only
nodes less than half a turn apart on them, so a straight edge is the shortest
way around; a query path is shifted by whole turns to start exactly at the
query configuration (its end is then the carry pose up to whole turns).
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import os
from pathlib import Path

import numpy as np
from scipy.sparse import csr_matrix
from scipy.sparse.csgraph import dijkstra

from vamg_drake.planning.collision_environment import CollisionEnvironment
from vamg_drake.planning.sphere_collision import SphereCollisionChecker
from vamg_drake.planning.whole_body_rrt import WholeBodySearchSpace
from vamg_drake.robot import layout


@dataclasses.dataclass
class ArmRoadmapConfig:
    """Roadmap parameters.

    Attributes:
        nodes: roadmap nodes (the carry pose included).
        neighbours: straight edges tried per node (nearest by sphere travel).
        seed: sampling seed (the roadmap is a pure function of the robot
            model, the carry pose and this config).
        query_candidates: roadmap nodes tried per query connection.
    """

    nodes: int = 300
    neighbours: int = 10
    seed: int = 0
    query_candidates: int = 12


_log = logging.getLogger(__name__)
_ARM = slice(3, None)
_CONT = layout.IS_CONTINUOUS[3:]


def _wrap(x: np.ndarray) -> np.ndarray:
    out = np.array(x, float, copy=True)
    out[..., _CONT] = layout.wrap_angle(out[..., _CONT])
    return out


class ArmRoadmap:
    """Self-collision-free roadmap over torso + arm (8,) toward a carry pose.

    Build with `ArmRoadmap.build` (or `for_checker`, cached per model).

    Attributes:
        nodes: (N, 8) configurations, node 0 the carry pose (wrapped).
        cost_to_carry: (N,) roadmap distance to node 0 [m of sphere travel]
            (inf: not connected).
        next_toward_carry: (N,) the next node on the way to node 0 (-1 at
            node 0 and unconnected nodes).
        edges: (E, 2) node pairs joined by a self-free straight motion.
        num_edges: E.
    """

    _CACHE: dict[bytes, "ArmRoadmap"] = {}

    def __init__(self, checker: SphereCollisionChecker, nodes: np.ndarray, cost_to_carry: np.ndarray,
                 next_toward_carry: np.ndarray, edges: np.ndarray, config: ArmRoadmapConfig):
        self.config = config
        self.nodes = nodes
        self.cost_to_carry = cost_to_carry
        self.next_toward_carry = next_toward_carry
        self.edges = np.asarray(edges, np.int64).reshape(-1, 2)
        self.num_edges = self.edges.shape[0]
        self._self_checker = checker.with_environment(CollisionEnvironment())
        self._space = WholeBodySearchSpace.fixed_base(self._self_checker, np.zeros(3))
        self._lever = np.asarray(checker.lever[_ARM], float)
        self._memo: dict = {}  # query results (pure functions of the roadmap and the query)

    @staticmethod
    def for_checker(checker: SphereCollisionChecker, carry: np.ndarray,
                    config: ArmRoadmapConfig | None = None) -> "ArmRoadmap":
        """The roadmap for this checker's robot model and self-collision
        padding and this carry pose: cached in memory, and on disk under
        `$VAMG_CACHE/arm_roadmap` (default ``~/.cache/vamg_drake``; built on
        first use, about 2 s)."""
        config = config or ArmRoadmapConfig()
        parts = [checker.sph_link, checker.sph_c, checker.sph_rs, checker.pairs, checker.lever,
                 np.asarray(carry, float), np.array([checker.config.motion_resolution, config.nodes,
                                                     config.neighbours, config.seed], float)]
        key = b"".join(np.ascontiguousarray(a).tobytes() for a in parts)
        roadmap = ArmRoadmap._CACHE.get(key)
        if roadmap is None:
            root = os.environ.get("VAMG_CACHE")
            folder = (Path(root) if root else Path.home() / ".cache" / "vamg_drake") / "arm_roadmap"
            path = folder / f"{hashlib.sha256(key).hexdigest()[:16]}.npz"
            try:
                with np.load(path) as f:
                    roadmap = ArmRoadmap(checker, f["nodes"], f["cost_to_carry"], f["next_toward_carry"],
                                         f["edges"], config)
            except (OSError, KeyError, ValueError):
                roadmap = ArmRoadmap.build(checker, carry, config)
                try:
                    folder.mkdir(parents=True, exist_ok=True)
                    tmp = path.with_suffix(f".{os.getpid()}.tmp.npz")
                    np.savez(tmp, nodes=roadmap.nodes, cost_to_carry=roadmap.cost_to_carry,
                             next_toward_carry=roadmap.next_toward_carry, edges=roadmap.edges)
                    os.replace(tmp, path)
                except OSError as e:
                    _log.warning("ArmRoadmap: could not cache the roadmap in %s (%s)", folder, e)
            ArmRoadmap._CACHE[key] = roadmap
        return roadmap

    @staticmethod
    def build(checker: SphereCollisionChecker, carry: np.ndarray, config: ArmRoadmapConfig | None = None) -> "ArmRoadmap":
        """Samples the roadmap (see the module docstring)."""
        config = config or ArmRoadmapConfig()
        if config.nodes < 2 or config.neighbours < 1:
            raise ValueError(f"ArmRoadmapConfig: nodes ({config.nodes}) must be >= 2 and neighbours "
                             f"({config.neighbours}) >= 1")
        carry = _wrap(np.asarray(carry, float).reshape(layout.NQ - 3))
        self_checker = checker.with_environment(CollisionEnvironment())
        if not self_checker.is_free(np.concatenate([np.zeros(3), carry])[None])[0]:
            raise ValueError("ArmRoadmap: the carry pose is in self-collision")
        rng = np.random.default_rng(config.seed)
        lo, hi = layout.SAMPLE_LOWER[_ARM], layout.SAMPLE_UPPER[_ARM]
        nodes = [carry[None]]
        count = 1
        for _ in range(100):
            if count >= config.nodes:
                break
            X = rng.uniform(lo, hi, (4 * config.nodes, lo.shape[0]))
            Q = np.concatenate([np.zeros((X.shape[0], 3)), X], axis=1)
            X = X[self_checker.is_free(Q)][: config.nodes - count]
            nodes.append(X)
            count += X.shape[0]
        nodes = np.concatenate(nodes)
        n = nodes.shape[0]
        lever = np.asarray(checker.lever[_ARM], float)
        diff = np.abs(nodes[:, None, :] - nodes[None, :, :])
        dist = diff @ lever
        # Continuous joints: only edges less than half a turn long on them.
        np.fill_diagonal(dist, np.inf)
        dist[np.any(diff[:, :, _CONT] >= np.pi, axis=2)] = np.inf
        space = WholeBodySearchSpace.fixed_base(self_checker, np.zeros(3))
        k = min(config.neighbours, n - 1)
        near = np.argsort(dist, axis=1, kind="stable")[:, :k]
        rows, cols, vals = [], [], []
        tried = set()
        for i in range(n):
            for j in near[i]:
                a, b = (i, int(j)) if i < j else (int(j), i)
                if (a, b) in tried or not np.isfinite(dist[a, b]):
                    continue
                tried.add((a, b))
                if space.motion_free(nodes[a], nodes[b]):
                    rows.append(a)
                    cols.append(b)
                    vals.append(dist[a, b])
        graph = csr_matrix((np.array(vals, float), (np.array(rows, int), np.array(cols, int))), shape=(n, n))
        cost, pred = dijkstra(graph, directed=False, indices=0, return_predecessors=True)
        pred = np.where(pred < 0, -1, pred).astype(np.int64)
        return ArmRoadmap(checker, nodes, cost, pred, np.column_stack([rows, cols]), config)

    def _remember(self, key, value):
        if len(self._memo) >= 256:
            self._memo.clear()
        self._memo[key] = value
        return value

    def self_free(self, W: np.ndarray) -> bool:
        """The torso + arm path W (K, 8) of straight segments is free of
        self-collision (at any base pose). Answers are remembered (the
        planner asks again in later stages and attempts)."""
        W = np.ascontiguousarray(W, float)
        key = ("free", W.shape, W.tobytes())
        if key in self._memo:
            return self._memo[key]
        return self._remember(key, all(self._space.motion_free(W[i], W[i + 1]) for i in range(W.shape[0] - 1)))

    def _distance(self, a: np.ndarray, X: np.ndarray) -> np.ndarray:
        return np.abs(X - a) @ self._lever

    def to_carry(self, x: np.ndarray) -> np.ndarray | None:
        """A self-collision-free path (M, 8) from x (torso + arm, free) to the
        carry pose (up to whole turns of continuous joints), or None when no
        candidate node is reachable by a straight self-free motion.

        The path starts exactly at x, follows the roadmap's shortest-path
        tree, and is shortened greedily (each waypoint joined to the
        farthest later one it reaches by a self-free straight motion)."""
        x = np.asarray(x, float).reshape(layout.NQ - 3)
        key = ("carry", x.tobytes())
        if key in self._memo:
            path = self._memo[key]
            return None if path is None else path.copy()
        path = self._to_carry(x)
        self._remember(key, path)
        return None if path is None else path.copy()

    def _to_carry(self, x: np.ndarray) -> np.ndarray | None:
        xw = _wrap(x)
        offset = x - xw
        d = self._distance(xw, self.nodes)
        d[np.any(np.abs(self.nodes[:, _CONT] - xw[_CONT]) >= np.pi, axis=1)] = np.inf
        total = d + self.cost_to_carry
        order = np.argsort(total, kind="stable")[: self.config.query_candidates]
        for i in order:
            if not np.isfinite(total[i]):
                break
            if not self._space.motion_free(xw, self.nodes[i]):
                continue
            chain = [xw]
            j = int(i)
            while j >= 0:
                chain.append(self.nodes[j])
                j = int(self.next_toward_carry[j])
            path = self._shorten(np.array(chain)) + offset
            path[0] = x  # exactly (the offset is whole turns, up to rounding)
            return path
        return None

    def _shorten(self, path: np.ndarray, motion_free=None) -> np.ndarray:
        """Each waypoint joined to the farthest later one it reaches freely."""
        motion_free = motion_free or self._space.motion_free
        out = [path[0]]
        i = 0
        n = path.shape[0]
        while i < n - 1:
            j = n - 1
            while j > i + 1 and not motion_free(path[i], path[j]):
                j -= 1
            out.append(path[j])
            i = j
        return np.array(out)

    def connect(self, a: np.ndarray, b: np.ndarray, state_free, motion_free, max_rounds: int = 30) -> np.ndarray | None:
        """A path (M, 8) from a to b (up to whole turns of continuous joints)
        through the roadmap that is valid for the caller's checks (e.g. the
        whole body at a fixed base pose, map included), or None.

        Lazy PRM (Bohlin & Kavraki 2000): the nodes are checked in one batch
        (`state_free(X (K, 8)) -> (K,) bool`); a and b (assumed valid) are
        joined to their `query_candidates` nearest nodes; the edges of the
        shortest roadmap path are checked (`motion_free(xa, xb) -> bool`;
        both checks are assumed to cover self-collision too); a blocked edge
        is removed and the search repeats, at most `max_rounds` times. The path starts exactly at a and is shortened
        greedily with `motion_free`.
        """
        a = np.asarray(a, float).reshape(layout.NQ - 3)
        b = np.asarray(b, float).reshape(layout.NQ - 3)
        aw, bw = _wrap(a), _wrap(b)
        n = self.nodes.shape[0]
        ia, ib = n, n + 1
        X = np.concatenate([self.nodes, aw[None], bw[None]])
        k = self.config.query_candidates
        ends = []
        for i_end, x in ((ia, aw), (ib, bw)):
            d = self._distance(x, self.nodes)
            d[np.any(np.abs(self.nodes[:, _CONT] - x[_CONT]) >= np.pi, axis=1)] = np.inf
            near = np.argsort(d, kind="stable")[:k]
            ends += [(i_end, int(j)) for j in near if np.isfinite(d[j])]
        edges = np.concatenate([self.edges, np.array(ends, np.int64).reshape(-1, 2)])
        weight = np.abs(X[edges[:, 0]] - X[edges[:, 1]]) @ self._lever + 1e-9
        edge_ok = np.zeros(edges.shape[0], np.int8)  # 0 unknown, 1 free, -1 blocked
        # All nodes in one batch (cheaper than one search round per blocked node).
        node_ok = np.ones(n + 2, np.int8)
        node_ok[:n] = np.where(np.asarray(state_free(self.nodes), bool), 1, -1)
        # Edge ids by (smaller, larger) node: one flat key per edge.
        key = np.minimum(edges[:, 0], edges[:, 1]) * (n + 2) + np.maximum(edges[:, 0], edges[:, 1])
        order = np.argsort(key, kind="stable")
        sorted_key = key[order]
        node_live = node_ok[edges[:, 0]] >= 0
        node_live &= node_ok[edges[:, 1]] >= 0
        for _ in range(max_rounds):
            live = node_live & (edge_ok >= 0)
            graph = csr_matrix((weight[live], (edges[live, 0], edges[live, 1])), shape=(n + 2, n + 2))
            dist, pred = dijkstra(graph, directed=False, indices=ia, return_predecessors=True)
            if not np.isfinite(dist[ib]):
                return None
            chain = [ib]
            while chain[-1] != ia:
                chain.append(int(pred[chain[-1]]))
            chain = chain[::-1]
            blocked = False
            for p, q in zip(chain[:-1], chain[1:]):
                e = order[np.searchsorted(sorted_key, min(p, q) * (n + 2) + max(p, q))]
                if edge_ok[e] == 0:
                    edge_ok[e] = 1 if motion_free(X[p], X[q]) else -1
                if edge_ok[e] < 0:
                    blocked = True
                    break
            if not blocked:
                path = self._shorten(X[chain], motion_free) + (a - aw)
                path[0] = a
                return path
        return None
