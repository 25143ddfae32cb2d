"""Pre-computed kinematic maps of the Fetch: reachability, capability, torso height.

All three are built from uniform joint samples of the torso + arm chain pushed
through the batched FK of `arm_chain` (paper appendix "Pre-computed Kinematic
Maps"), expressed in the base frame B:

* **Reachability** -- 6D voxels of X_BG (position 5 cm, ZYX Euler angles pi/8):
  visitation count and the maximum Yoshikawa manipulability sqrt(det(J J^T)).
  Stored sparsely (sorted int64 voxel keys), voxels below the floor dropped.
* **Capability** -- the inverted view: "is this end-effector pose relative to
  the base reachable?" A pose is capable when its voxel (or, with the default
  default neighbourhood, a voxel within one orientation cell in yaw, pitch and
  roll) has been visited. Sampling leaves holes in a sparse 6D grid; the
  neighbourhood closes them so the filter stays a cheap *necessary* condition
  (IK decides). Measured with the default maps on 3,000 random poses: 99.7% of
  FK-reachable poses pass; of the poses it rejects, IK (8 restarts) fails on
  99.6%.
* **Torso height** -- 2 cm end-effector position bins x 5 cm torso bins; each
  position bin stores the torso height with the most samples (argmax count,
  counted over the 3x3x3 neighbouring bins: with 5x fewer samples than the
  paper the raw per-bin argmax is noise).

The paper samples 1.28e8 / 3e8 configurations on a GPU; the defaults here
(2**25 / 2**26) build in a few minutes on two CPU cores. Maps are cached on
disk under ``$VAMG_CACHE/maps`` (default ``~/.cache/vamg_drake/maps``) in a
folder named by the hash of ``models/fetch/fetch.urdf`` and of the map config,
so a changed robot model or resolution rebuilds them.
"""

import dataclasses as dc
import hashlib
import json
import logging
import math
import os
import time
from pathlib import Path

import numba
import numpy as np
from scipy import ndimage
from tqdm import tqdm

from vamg_drake.policy.arm_chain import CHAIN_CONTINUOUS, N_CHAIN, ArmChain
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import model_hash

_log = logging.getLogger(__name__)

N_YAW = 16  # 2 pi / (pi / 8)
N_PITCH = 8  # pi / (pi / 8)
N_ROLL = 16
N_ORIENTATION = N_YAW * N_PITCH * N_ROLL
#: Bumped when the on-disk format changes (part of the cache folder name).
FORMAT_VERSION = 2


#: The reachability arrays as the maps use them (16 M voxels: decompressing and
#: converting the compressed file costs about 2 s per episode), stored beside
#: it uncompressed on first load and memory-mapped after: every episode process
#: shares the operating system's page cache instead of decoding its own copy.
_DECODED_DTYPES = {"keys": np.int64, "count": np.int32, "manipulability": np.float32}
#: Written last; names the compressed file's size and mtime the arrays decode.
_DECODED_STAMP = "reachability.decoded.json"


def _reachability_stamp(folder: Path) -> dict:
    stat = (folder / "reachability.npz").stat()
    return {"source_size": stat.st_size, "source_mtime_ns": stat.st_mtime_ns}


def _load_decoded(folder: Path, stamp: dict) -> dict[str, np.ndarray] | None:
    """The memory-mapped decoded arrays, or None when they are absent, stale
    (the compressed file changed since) or unreadable."""
    try:
        if json.loads((folder / _DECODED_STAMP).read_text()) != stamp:
            return None
        # np.asarray: plain read-only ndarray views of the maps (no memmap subclass in the lookups).
        arrays = {name: np.asarray(np.load(folder / f"reachability.{name}.npy", mmap_mode="r"))
                  for name in _DECODED_DTYPES}
    except (OSError, ValueError):
        return None
    size = arrays["keys"].shape
    if any(a.dtype != _DECODED_DTYPES[n] or a.shape != size or a.ndim != 1 for n, a in arrays.items()):
        return None
    return arrays


def _decode_and_store(folder: Path, f, stamp: dict) -> dict[str, np.ndarray]:
    """Decodes the open compressed file ``f`` and stores the arrays for the
    next load (atomically, the stamp last); a cache folder that cannot be
    written costs only the decoding."""
    arrays = {
        "keys": np.cumsum(f["key_deltas"].astype(np.int64)),
        "count": f["count"].astype(np.int32),
        "manipulability": f["manipulability"].astype(np.float32),
    }
    tag = f"{os.getpid()}.tmp"
    try:
        for name, array in arrays.items():
            tmp = folder / f"reachability.{name}.{tag}.npy"
            np.save(tmp, array)
            os.replace(tmp, folder / f"reachability.{name}.npy")
        tmp = folder / f"{_DECODED_STAMP}.{tag}"
        tmp.write_text(json.dumps(stamp))
        os.replace(tmp, folder / _DECODED_STAMP)
    except OSError as e:
        _log.info("kinematic maps: decoded arrays not stored in %s (%s); decoding on every load", folder, e)
    finally:
        for tmp in folder.glob(f"*.{tag}*"):
            tmp.unlink(missing_ok=True)
    return arrays


@dc.dataclass
class KinematicMapsConfig:
    """Resolution, extent and sample counts of the kinematic maps."""

    #: Joint samples for the reachability/capability map (paper: 1.28e8).
    reach_samples: int = 2**25
    #: Joint samples for the torso-height map (paper: 3e8).
    torso_samples: int = 2**26
    #: Position resolution of the 6D voxels [m] (paper: 0.05).
    position_resolution: float = 0.05
    #: Orientation resolution of the 6D voxels [rad] (paper: pi/8; fixed by N_YAW etc.).
    angle_resolution: float = math.pi / 8
    #: End-effector position bins of the torso map [m] (paper: 0.02).
    torso_position_resolution: float = 0.02
    #: Torso height bins [m] (paper: 0.05).
    torso_bin: float = 0.05
    #: Counts are summed over this many neighbouring position bins per axis before
    #: the argmax (1 = the paper's raw argmax); compensates for 5x fewer samples.
    torso_smoothing_cells: int = 3
    #: Lower corner and size of the base-frame box the maps cover [m].
    box_lower: list[float] = dc.field(default_factory=lambda: [-1.2, -1.4, 0.0])
    box_size: list[float] = dc.field(default_factory=lambda: [2.6, 2.8, 2.2])
    batch: int = 1 << 20
    seed: int = 0

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Raises ValueError naming the bad field."""
        max_key = int(np.prod(self.grid_shape(self.position_resolution))) * N_ORIENTATION
        if max_key >= 2**32:
            raise ValueError("KinematicMapsConfig: box_size / position_resolution give more than 2**32 voxels")
        if abs(self.angle_resolution - math.pi / 8) > 1e-9:
            raise ValueError("KinematicMapsConfig.angle_resolution: only pi/8 is supported")
        for name in ("reach_samples", "torso_samples", "batch"):
            if getattr(self, name) < 1:
                raise ValueError(f"KinematicMapsConfig.{name} must be >= 1, got {getattr(self, name)}")
        if len(self.box_lower) != 3 or len(self.box_size) != 3 or min(self.box_size) <= 0:
            raise ValueError("KinematicMapsConfig.box_lower / box_size must be 3-vectors with positive sizes")
        for name in ("position_resolution", "torso_position_resolution", "torso_bin"):
            if not getattr(self, name) > 0:
                raise ValueError(f"KinematicMapsConfig.{name} must be > 0, got {getattr(self, name)}")

    def grid_shape(self, resolution: float) -> tuple[int, int, int]:
        return tuple(int(math.ceil(s / resolution)) for s in self.box_size)  # type: ignore[return-value]

    def digest(self) -> str:
        """A short hash of every field (part of the cache key)."""
        text = json.dumps(dc.asdict(self), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()[:12]


def default_cache_dir() -> Path:
    """``$VAMG_CACHE/maps`` or ``~/.cache/vamg_drake/maps``."""
    root = os.environ.get("VAMG_CACHE")
    return (Path(root) if root else Path.home() / ".cache" / "vamg_drake") / "maps"


# ---------------------------------------------------------------------------
# Voxel keys.


@numba.njit(cache=True)
def _position_cell(px, py, pz, lower, resolution, shape):
    ix = int(math.floor((px - lower[0]) / resolution))
    iy = int(math.floor((py - lower[1]) / resolution))
    iz = int(math.floor((pz - lower[2]) / resolution))
    if ix < 0 or iy < 0 or iz < 0 or ix >= shape[0] or iy >= shape[1] or iz >= shape[2]:
        return -1
    return (ix * shape[1] + iy) * shape[2] + iz


@numba.njit(cache=True)
def _orientation_cell(R):
    yaw = math.atan2(R[1, 0], R[0, 0])
    pitch = math.asin(min(1.0, max(-1.0, -R[2, 0])))
    roll = math.atan2(R[2, 1], R[2, 2])
    step = math.pi / 8
    iy = min(N_YAW - 1, int(math.floor((yaw + math.pi) / step)))
    ip = min(N_PITCH - 1, int(math.floor((pitch + math.pi / 2) / step)))
    ir = min(N_ROLL - 1, int(math.floor((roll + math.pi) / step)))
    return (iy * N_PITCH + ip) * N_ROLL + ir


@numba.njit(cache=True, parallel=True)
def _pose_keys(X, lower, resolution, shape, keys):
    for b in numba.prange(X.shape[0]):
        c = _position_cell(X[b, 0, 3], X[b, 1, 3], X[b, 2, 3], lower, resolution, shape)
        keys[b] = -1 if c < 0 else c * N_ORIENTATION + _orientation_cell(X[b, :3, :3])


@numba.njit(cache=True, parallel=True)
def _manipulability(J, out):
    """out[b] = Yoshikawa's sqrt(det(J J^T)) of the Jacobians J (B, 6, 8)."""
    for b in numba.prange(J.shape[0]):
        d = np.linalg.det(J[b] @ J[b].T)
        out[b] = math.sqrt(d) if d > 0.0 else 0.0


@numba.njit(cache=True, parallel=True)
def _torso_cells(X, torso, lower, resolution, shape, torso_bin, n_torso, cells):
    """cells[b] = end-effector position bin of X[b] x torso bin of torso[b], -1 outside the box."""
    for b in numba.prange(X.shape[0]):
        c = _position_cell(X[b, 0, 3], X[b, 1, 3], X[b, 2, 3], lower, resolution, shape)
        cells[b] = -1 if c < 0 else c * n_torso + min(n_torso - 1, int(torso[b] / torso_bin))


#: Configurations pushed through the chain FK at once while building.
_CHUNK = 1 << 16


def _reach_batch(chain: ArmChain, q: np.ndarray, lower: np.ndarray, resolution: float, shape: np.ndarray):
    """(voxel keys (B,), manipulability (B,)) of the chain configurations q (B, 8)."""
    keys = np.empty(q.shape[0], dtype=np.int64)
    manip = np.empty(q.shape[0], dtype=np.float64)
    for s in range(0, q.shape[0], _CHUNK):
        X, J = chain.forward(q[s:s + _CHUNK], with_jacobian=True)
        _pose_keys(X, lower, resolution, shape, keys[s:s + _CHUNK])
        _manipulability(J, manip[s:s + _CHUNK])
    return keys, np.where(keys >= 0, manip, 0.0)


def _torso_batch(chain: ArmChain, q: np.ndarray, lower: np.ndarray, resolution: float, shape: np.ndarray,
                 torso_bin: float, n_torso: int) -> np.ndarray:
    """Torso-height map cells (B,) of the chain configurations q (B, 8), -1 outside the box."""
    cells = np.empty(q.shape[0], dtype=np.int64)
    for s in range(0, q.shape[0], _CHUNK):
        X = chain.forward(q[s:s + _CHUNK])
        _torso_cells(X, np.ascontiguousarray(q[s:s + _CHUNK, 0]), lower, resolution, shape, torso_bin, n_torso,
                     cells[s:s + _CHUNK])
    return cells


def _sample_chain(rng: np.random.Generator, n: int) -> np.ndarray:
    lower = layout.SAMPLE_LOWER[layout.TORSO_ARM]
    upper = layout.SAMPLE_UPPER[layout.TORSO_ARM]
    return rng.uniform(lower, upper, (n, N_CHAIN))


def _reduce_keys(keys: np.ndarray, counts: np.ndarray, manip: np.ndarray):
    order = np.argsort(keys, kind="stable")
    keys, counts, manip = keys[order], counts[order], manip[order]
    unique, start = np.unique(keys, return_index=True)
    return unique, np.add.reduceat(counts, start), np.maximum.reduceat(manip, start)


# ---------------------------------------------------------------------------
# The maps.


@dc.dataclass(frozen=True)
class ReachabilityMap:
    """Sparse 6D voxel map of base-frame end-effector poses X_BG.

    Attributes:
        keys: (V,) sorted int64 voxel keys (position cell * N_ORIENTATION + orientation cell).
        count: (V,) visitation counts.
        manipulability: (V,) max Yoshikawa manipulability per voxel.
    """

    keys: np.ndarray
    count: np.ndarray
    manipulability: np.ndarray
    box_lower: np.ndarray
    resolution: float
    shape: tuple[int, int, int]

    def voxel_keys(self, X_BG: np.ndarray) -> np.ndarray:
        """Voxel keys (B,) of poses X_BG (B, 4, 4); -1 outside the map's box."""
        X = np.ascontiguousarray(np.reshape(X_BG, (-1, 4, 4)), dtype=float)
        keys = np.empty(X.shape[0], dtype=np.int64)
        _pose_keys(X, np.asarray(self.box_lower, float), self.resolution, np.asarray(self.shape, np.int64), keys)
        return keys

    def lookup(self, keys: np.ndarray) -> np.ndarray:
        """Index into ``keys``/``count`` of each query key, -1 when not visited."""
        pos = np.searchsorted(self.keys, keys)
        pos = np.minimum(pos, max(0, self.keys.size - 1))
        hit = (keys >= 0) & (self.keys.size > 0) & (self.keys[pos] == keys)
        return np.where(hit, pos, -1)

    def query(self, X_BG: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(count, manipulability) of each pose's voxel (0 where never visited)."""
        idx = self.lookup(self.voxel_keys(X_BG))
        hit = idx >= 0
        return np.where(hit, self.count[idx], 0), np.where(hit, self.manipulability[idx], 0.0)


@dc.dataclass(frozen=True)
class CapabilityMap:
    """"Given an end-effector pose relative to the base, is it reachable?"

    The inverted reachability map: a pose X_BG is capable when a voxel within
    ``position_neighbourhood`` cells of its own in x, y, z and within
    ``orientation_neighbourhood`` cells in yaw, pitch, roll was visited while
    building the reachability map. The neighbourhood closes the sampling holes
    of the sparse 6D grid so that the filter stays a cheap *necessary*
    condition (IK decides); `tests/test_policy_kinematic_maps.py` measures its
    agreement with IK.
    """

    reachability: ReachabilityMap
    position_neighbourhood: int = 0
    orientation_neighbourhood: int = 1

    def is_reachable(self, X_BG: np.ndarray) -> np.ndarray:
        """True (B,) for poses X_BG (B, 4, 4) the arm can (probably) reach from the base."""
        r = self.reachability
        keys = r.voxel_keys(X_BG)
        kp, ko = self.position_neighbourhood, self.orientation_neighbourhood
        if kp == 0 and ko == 0:
            return r.lookup(keys) >= 0
        pos_cell, ori = np.divmod(keys, N_ORIENTATION)
        nx, ny, nz = r.shape
        ix, rem = np.divmod(pos_cell, ny * nz)
        iy, iz = np.divmod(rem, nz)
        yaw, rem = np.divmod(ori, N_PITCH * N_ROLL)
        pitch, roll = np.divmod(rem, N_ROLL)
        dp, do = np.arange(-kp, kp + 1), np.arange(-ko, ko + 1)
        grid = np.stack(np.meshgrid(dp, dp, dp, do, do, do, indexing="ij"), -1).reshape(-1, 6)
        jx = ix[:, None] + grid[None, :, 0]
        jy = iy[:, None] + grid[None, :, 1]
        jz = iz[:, None] + grid[None, :, 2]
        jyaw = (yaw[:, None] + grid[None, :, 3]) % N_YAW
        jpitch = pitch[:, None] + grid[None, :, 4]
        jroll = (roll[:, None] + grid[None, :, 5]) % N_ROLL
        inside = (
            (jx >= 0) & (jx < nx) & (jy >= 0) & (jy < ny) & (jz >= 0) & (jz < nz)
            & (jpitch >= 0) & (jpitch < N_PITCH)
        )
        nkeys = ((jx * ny + jy) * nz + jz) * N_ORIENTATION + (jyaw * N_PITCH + jpitch) * N_ROLL + jroll
        nkeys = np.where(inside & (keys[:, None] >= 0), nkeys, -1)
        return np.any(r.lookup(nkeys.ravel()).reshape(nkeys.shape) >= 0, axis=1)


@dc.dataclass(frozen=True)
class TorsoHeightMap:
    """Best torso height per base-frame end-effector position bin.

    Attributes:
        best_bin: (nx, ny, nz) int8 torso bin with the most samples, -1 if none.
        count: (nx, ny, nz) samples in the best bin (int32).
    """

    best_bin: np.ndarray
    count: np.ndarray
    box_lower: np.ndarray
    resolution: float
    torso_bin: float

    def _cells(self, p_BE: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p = np.reshape(p_BE, (-1, 3))
        idx = np.floor((p - self.box_lower) / self.resolution).astype(np.int64)
        inside = np.all((idx >= 0) & (idx < np.array(self.best_bin.shape)), axis=1)
        return np.where(inside[:, None], idx, 0), inside

    def best_torso(self, p_BE: np.ndarray) -> np.ndarray:
        """Torso height (B,) for end-effector positions p_BE (B, 3); NaN where never reached."""
        idx, inside = self._cells(p_BE)
        b = self.best_bin[idx[:, 0], idx[:, 1], idx[:, 2]]
        h = np.minimum((b + 0.5) * self.torso_bin, layout.Q_UPPER[layout.TORSO])
        return np.where(inside & (b >= 0), h, np.nan)

    def horizontal_reach(self) -> tuple[float, float]:
        """(min, max) horizontal distance from the base origin of any reached bin [m]."""
        ix, iy, _ = np.nonzero(self.best_bin >= 0)
        x = self.box_lower[0] + (ix + 0.5) * self.resolution
        y = self.box_lower[1] + (iy + 0.5) * self.resolution
        r = np.hypot(x, y)
        return (float(r.min()), float(r.max())) if r.size else (0.0, 0.0)


@dc.dataclass(frozen=True)
class KinematicMaps:
    """The three maps plus what built them."""

    reachability: ReachabilityMap
    capability: CapabilityMap
    torso_height: TorsoHeightMap
    metadata: dict

    # -- building -----------------------------------------------------------

    @staticmethod
    def build(config: KinematicMapsConfig | None = None, progress: bool = True) -> "KinematicMaps":
        """Samples the chain and builds all three maps (minutes for the defaults)."""
        config = config or KinematicMapsConfig()
        config.validate()
        chain = ArmChain.load()
        rng = np.random.default_rng(config.seed)
        lower = np.asarray(config.box_lower, dtype=float)
        t0 = time.perf_counter()

        shape6 = np.asarray(config.grid_shape(config.position_resolution), dtype=np.int64)
        parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        done = 0
        with tqdm(total=config.reach_samples, desc="reachability map", unit="q", unit_scale=True, disable=not progress) as bar:
            while done < config.reach_samples:
                n = min(config.batch, config.reach_samples - done)
                q = _sample_chain(rng, n)
                keys, manip = _reach_batch(chain, q, lower, config.position_resolution, shape6)
                ok = keys >= 0
                parts.append(_reduce_keys(keys[ok], np.ones(np.count_nonzero(ok), np.int64), manip[ok]))
                if len(parts) >= 8:
                    parts = [_reduce_keys(*map(np.concatenate, zip(*parts)))]
                done += n
                bar.update(n)
        keys, count, manip = _reduce_keys(*map(np.concatenate, zip(*parts)))
        reach = ReachabilityMap(
            keys, count.astype(np.int32), manip.astype(np.float32), lower, config.position_resolution, tuple(int(s) for s in shape6)
        )
        t_reach = time.perf_counter() - t0

        t1 = time.perf_counter()
        shape3 = config.grid_shape(config.torso_position_resolution)
        n_torso = int(math.ceil(layout.Q_UPPER[layout.TORSO] / config.torso_bin))
        n_bins = int(np.prod(shape3)) * n_torso
        counts = np.zeros(n_bins, dtype=np.int64)
        done = 0
        with tqdm(total=config.torso_samples, desc="torso-height map", unit="q", unit_scale=True, disable=not progress) as bar:
            while done < config.torso_samples:
                n = min(config.batch, config.torso_samples - done)
                q = _sample_chain(rng, n)
                cells = _torso_batch(chain, q, lower, config.torso_position_resolution, np.asarray(shape3, np.int64),
                                     config.torso_bin, n_torso)
                counts += np.bincount(cells[cells >= 0], minlength=n_bins)
                done += n
                bar.update(n)
        counts = counts.reshape(*shape3, n_torso)
        reached = counts.sum(axis=-1) > 0
        k = config.torso_smoothing_cells
        if k > 1:
            counts = ndimage.uniform_filter(counts.astype(np.float32), size=(k, k, k, 1), mode="constant") * k**3
        best = np.argmax(counts, axis=-1).astype(np.int8)
        best_count = np.rint(np.max(counts, axis=-1)).astype(np.int32)
        best[~reached] = -1
        best_count[~reached] = 0
        torso = TorsoHeightMap(best, best_count, lower, config.torso_position_resolution, config.torso_bin)
        t_torso = time.perf_counter() - t1

        metadata = {
            "model_hash": model_hash(),
            "config_digest": config.digest(),
            "config": dc.asdict(config),
            "reach_build_s": round(t_reach, 2),
            "torso_build_s": round(t_torso, 2),
            "reach_voxels": int(keys.size),
            "torso_bins_reached": int(np.count_nonzero(best >= 0)),
            "continuous_joints_sampled_in": "[-pi, pi]" if CHAIN_CONTINUOUS.any() else "n/a",
        }
        return KinematicMaps(reach, CapabilityMap(reach), torso, metadata)

    # -- storage ------------------------------------------------------------

    @staticmethod
    def cache_folder(config: KinematicMapsConfig | None = None, cache_dir: Path | None = None) -> Path:
        config = config or KinematicMapsConfig()
        return Path(cache_dir or default_cache_dir()) / f"fetch-{model_hash()}-{config.digest()}-v{FORMAT_VERSION}"

    def save(self, folder: Path) -> None:
        """Writes the maps into `folder`, each file atomically (a temporary
        file renamed into place, meta.json last): processes that build the
        same maps at once, or a reader meanwhile, never see a partial file."""
        folder = Path(folder)
        folder.mkdir(parents=True, exist_ok=True)
        r, t = self.reachability, self.torso_height
        tag = f"{os.getpid()}.tmp"
        (folder / _DECODED_STAMP).unlink(missing_ok=True)  # the decoded arrays describe the old file

        def replace_into_place(name: str, write) -> None:
            tmp = folder / f"{Path(name).stem}.{tag}{Path(name).suffix}"
            try:
                write(tmp)
                os.replace(tmp, folder / name)
            finally:
                tmp.unlink(missing_ok=True)

        # Sorted keys fit in uint32 (checked by the config); their deltas compress well.
        replace_into_place("reachability.npz", lambda path: np.savez_compressed(
            path,
            key_deltas=np.diff(r.keys, prepend=0).astype(np.uint32),
            count=np.minimum(r.count, np.iinfo(np.uint16).max).astype(np.uint16),
            manipulability=r.manipulability.astype(np.float16),
            box_lower=r.box_lower, resolution=r.resolution, shape=np.asarray(r.shape),
        ))
        replace_into_place("torso_height.npz", lambda path: np.savez_compressed(
            path, best_bin=t.best_bin, count=t.count, box_lower=t.box_lower,
            resolution=t.resolution, torso_bin=t.torso_bin,
        ))
        replace_into_place("meta.json", lambda path: path.write_text(json.dumps(self.metadata, indent=2)))

    @staticmethod
    def load(folder: Path) -> "KinematicMaps":
        """Loads maps saved by `save`; FileNotFoundError names the missing file."""
        folder = Path(folder)
        for name in ("reachability.npz", "torso_height.npz", "meta.json"):
            if not (folder / name).exists():
                raise FileNotFoundError(f"kinematic maps: missing {folder / name}")
        stamp = _reachability_stamp(folder)  # before opening: a file replaced meanwhile is never stamped
        with np.load(folder / "reachability.npz") as f:
            arrays = _load_decoded(folder, stamp) or _decode_and_store(folder, f, stamp)
            reach = ReachabilityMap(
                arrays["keys"], arrays["count"], arrays["manipulability"], f["box_lower"], float(f["resolution"]),
                tuple(int(s) for s in f["shape"]),
            )
        with np.load(folder / "torso_height.npz") as f:
            torso = TorsoHeightMap(f["best_bin"], f["count"], f["box_lower"], float(f["resolution"]), float(f["torso_bin"]))
        metadata = json.loads((folder / "meta.json").read_text())
        if metadata.get("model_hash") != model_hash():
            raise ValueError(f"kinematic maps in {folder} were built for another robot model")
        return KinematicMaps(reach, CapabilityMap(reach), torso, metadata)

    @staticmethod
    def load_or_build(
        config: KinematicMapsConfig | None = None,
        cache_dir: Path | None = None,
        progress: bool = True,
    ) -> "KinematicMaps":
        """Loads the cached maps for this robot model and config, building them
        if missing, and rebuilding them if a cached file does not load (cut
        short, corrupted, or of another format): a bad cache costs one
        rebuild, never an episode."""
        config = config or KinematicMapsConfig()
        folder = KinematicMaps.cache_folder(config, cache_dir)
        try:
            return KinematicMaps.load(folder)
        except FileNotFoundError as e:
            reason = f"{e}; building kinematic maps now (one-time, cached in {folder})"
        except Exception as e:  # noqa: BLE001 - zipfile, numpy, json and key errors of a damaged file
            reason = (f"kinematic maps cache in {folder} does not load ({type(e).__name__}: {e}); "
                      "rebuilding it")
        _log.warning("%s", reason)
        if progress:
            print(f"[vamg] {reason}", flush=True)
        maps = KinematicMaps.build(config, progress=progress)
        maps.save(folder)
        return maps

    def size_bytes(self, folder: Path) -> int:
        return sum(p.stat().st_size for p in Path(folder).iterdir() if p.is_file())
