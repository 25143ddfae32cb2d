"""Arm chain FK/Jacobian, the IK solvers and the kinematic maps."""

from __future__ import annotations

import dataclasses as dc
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from vamg_drake.policy.arm_chain import ArmChain, base_poses
from vamg_drake.policy.ik import DrakeIk, FastIk, IkConfig
from vamg_drake.policy.kinematic_maps import KinematicMaps, KinematicMapsConfig
from vamg_drake.robot import layout
from vamg_drake.robot.kinematics import FetchKinematics

#: Agreement tolerances of the capability map with IK (measured: 99.7% / 99.6% / 61%).
RECALL_MIN = 0.97
REJECT_AGREES_MIN = 0.97
ACCEPT_PRECISION_MIN = 0.40


def _random_q(n: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    q = rng.uniform(layout.SAMPLE_LOWER, layout.SAMPLE_UPPER, (n, layout.NQ))
    q[:, layout.BASE_XY] = rng.uniform(-2.0, 2.0, (n, 2))
    return q


@pytest.fixture(scope="module")
def maps() -> KinematicMaps:
    # The default maps: built once on first use (a few minutes) and cached.
    return KinematicMaps.load_or_build()


def test_chain_matches_fetch_kinematics_and_jacobian() -> None:
    q = _random_q(50, 0)
    X, J = ArmChain.load().forward(q[:, layout.TORSO_ARM], with_jacobian=True)
    np.testing.assert_allclose(base_poses(q) @ X, FetchKinematics.instance().gripper_pose(q), atol=1e-12)
    eps = 1e-6
    for j in range(8):
        dq = q[:, layout.TORSO_ARM].copy()
        dq[:, j] += eps
        X1 = ArmChain.load().forward(dq)
        np.testing.assert_allclose((X1[:, :3, 3] - X[:, :3, 3]) / eps, J[:, :3, j], atol=1e-5)
        dR = X1[:, :3, :3] @ np.swapaxes(X[:, :3, :3], 1, 2)
        w = np.stack([dR[:, 2, 1] - dR[:, 1, 2], dR[:, 0, 2] - dR[:, 2, 0], dR[:, 1, 0] - dR[:, 0, 1]], 1) / (2 * eps)
        np.testing.assert_allclose(w, J[:, 3:, j], atol=1e-5)


def test_fast_ik_arm_only_reaches_fk_poses() -> None:
    q = _random_q(300, 1)
    X_WG = FetchKinematics.instance().gripper_pose(q)
    seed = np.tile(layout.stow_configuration(0, 0, 0), (300, 1))
    seed[:, :4] = q[:, :4]  # base and torso fixed at the truth
    ik = FastIk()
    q_sol, ok = ik.solve_arm(X_WG, seed)
    assert ok.mean() >= 0.95
    X_sol = FetchKinematics.instance().gripper_pose(q_sol[ok])
    assert np.max(np.linalg.norm(X_sol[:, :3, 3] - X_WG[ok, :3, 3], axis=1)) <= ik.config.position_tolerance
    angle = np.linalg.norm(Rotation.from_matrix(np.swapaxes(X_sol[:, :3, :3], 1, 2) @ X_WG[ok, :3, :3]).as_rotvec(), axis=1)
    assert np.max(angle) <= ik.config.angle_tolerance + 1e-9
    np.testing.assert_array_equal(q_sol[:, :4], seed[:, :4])
    cont = q_sol[:, layout.IS_CONTINUOUS]
    assert np.all((cont >= -np.pi) & (cont < np.pi))
    assert np.all(layout.within_limits(q_sol))


def test_fast_ik_fails_out_of_reach() -> None:
    X = np.tile(np.eye(4), (5, 1, 1))
    X[:, 0, 3] = 3.0  # 3 m in front of the base
    _, ok = FastIk().solve_arm(X, layout.stow_configuration(0, 0, 0))
    assert not ok.any()


def test_drake_ik_arm_only_and_whole_body() -> None:
    q = _random_q(6, 2)
    X_WG = FetchKinematics.instance().gripper_pose(q)
    ik = DrakeIk()
    n_ok = 0
    for i in range(6):
        seed = layout.stow_configuration(*q[i, :3])
        seed[layout.TORSO] = q[i, layout.TORSO]
        q_sol, ok = ik.solve(X_WG[i], seed)
        if ok:
            n_ok += 1
            np.testing.assert_allclose(q_sol[:4], seed[:4], atol=1e-9)
            X = FetchKinematics.instance().gripper_pose(q_sol)
            assert np.linalg.norm(X[:3, 3] - X_WG[i, :3, 3]) <= ik.config.position_tolerance + 1e-6
    assert n_ok >= 4
    # Whole body: the base is free to move to a far target.
    target = X_WG[0].copy()
    q_sol, ok = ik.solve(target, layout.stow_configuration(q[0, 0] - 1.0, q[0, 1], q[0, 2]), fix_base=False, fix_torso=False)
    assert ok
    np.testing.assert_allclose(FetchKinematics.instance().gripper_pose(q_sol)[:3, 3], target[:3, 3], atol=3e-3)


def test_capability_agrees_with_ik(maps: KinematicMaps) -> None:
    # Direction 1: poses reached by FK (above the floor) are capable.
    rng = np.random.default_rng(5)
    q = rng.uniform(layout.SAMPLE_LOWER[layout.TORSO_ARM], layout.SAMPLE_UPPER[layout.TORSO_ARM], (2000, 8))
    X = ArmChain.load().forward(q)
    X = X[X[:, 2, 3] > 0.05]
    assert maps.capability.is_reachable(X).mean() >= RECALL_MIN
    # Direction 2: random workspace poses the map rejects are rejected by IK too.
    n = 1500
    X = np.tile(np.eye(4), (n, 1, 1))
    X[:, :3, :3] = Rotation.random(n, random_state=3).as_matrix()
    X[:, :3, 3] = rng.uniform([-0.5, -1.1, 0.0], [1.2, 1.1, 1.8], (n, 3))
    _, ok = FastIk(IkConfig(restarts=8)).solve_chain(X, np.r_[0.2, layout.Q_ARM_STOW], torso_fixed=False)
    capable = maps.capability.is_reachable(X)
    assert (~capable).sum() > 100 and ok.sum() > 50
    assert 1.0 - ok[~capable].mean() >= REJECT_AGREES_MIN
    assert ok[capable].mean() >= ACCEPT_PRECISION_MIN
    # Reachability counts and manipulability are positive exactly where visited.
    count, manip = maps.reachability.query(X)
    assert np.all((count > 0) == (manip > 0) | (count > 0))
    assert np.all(manip >= 0)


def test_torso_height_map(maps: KinematicMaps) -> None:
    t = maps.torso_height
    h = t.best_torso(np.array([[0.6, 0.0, 1.7], [0.6, 0.0, 0.3], [5.0, 0.0, 1.0]]))
    assert np.isnan(h[2])  # never reached
    # Near the top of the workspace only a raised torso reaches; low targets favour a low one.
    assert 0.25 <= h[0] <= layout.Q_UPPER[layout.TORSO]
    assert 0.0 <= h[1] <= 0.15
    lo, hi = t.horizontal_reach()
    assert 0.9 < hi < 1.4


def test_missing_maps_are_built_on_demand(tmp_path, capsys) -> None:
    config = KinematicMapsConfig(reach_samples=20_000, torso_samples=20_000)
    maps = KinematicMaps.load_or_build(config, cache_dir=tmp_path, progress=True)
    out = capsys.readouterr().out
    assert "missing" in out and "building kinematic maps" in out
    folder = KinematicMaps.cache_folder(config, tmp_path)
    meta = json.loads((folder / "meta.json").read_text())
    assert meta["config"]["reach_samples"] == 20_000 and meta["reach_voxels"] == maps.reachability.keys.size
    again = KinematicMaps.load_or_build(config, cache_dir=tmp_path, progress=True)
    assert "building" not in capsys.readouterr().out
    np.testing.assert_array_equal(again.reachability.keys, maps.reachability.keys)
    np.testing.assert_array_equal(again.torso_height.best_bin, maps.torso_height.best_bin)


@pytest.mark.parametrize("damage", ["truncate", "garbage", "meta"])
def test_a_corrupt_cache_file_is_rebuilt(tmp_path, capsys, damage) -> None:
    config = KinematicMapsConfig(reach_samples=20_000, torso_samples=20_000)
    maps = KinematicMaps.load_or_build(config, cache_dir=tmp_path, progress=False)
    folder = KinematicMaps.cache_folder(config, tmp_path)
    reach = folder / "reachability.npz"
    if damage == "truncate":
        reach.write_bytes(reach.read_bytes()[: reach.stat().st_size // 2])
    elif damage == "garbage":
        reach.write_bytes(b"not a zip file")
    else:
        (folder / "meta.json").write_text("{")
    capsys.readouterr()
    again = KinematicMaps.load_or_build(config, cache_dir=tmp_path, progress=True)
    assert "does not load" in capsys.readouterr().out
    np.testing.assert_array_equal(again.reachability.keys, maps.reachability.keys)
    KinematicMaps.load(folder)  # the rebuilt cache loads again


def test_a_save_interrupted_midway_leaves_no_partial_file(tmp_path, monkeypatch) -> None:
    """Two benchmark workers may build the same maps at once and a third may
    load them meanwhile: every file appears whole (renamed into place) or not
    at all, so an interrupted save is a missing map (rebuilt), not a corrupt one."""
    config = KinematicMapsConfig(reach_samples=20_000, torso_samples=20_000)
    maps = KinematicMaps.build(config, progress=False)
    folder = tmp_path / "maps"
    real_savez = np.savez_compressed

    def savez_then_crash(path, **arrays):
        real_savez(path, **arrays)
        if "best_bin" in arrays:  # the second file: written, then the process dies
            raise KeyboardInterrupt

    monkeypatch.setattr(np, "savez_compressed", savez_then_crash)
    with pytest.raises(KeyboardInterrupt):
        maps.save(folder)
    monkeypatch.undo()
    assert sorted(p.name for p in folder.iterdir()) == ["reachability.npz"]
    with pytest.raises(FileNotFoundError, match="torso_height.npz"):
        KinematicMaps.load(folder)
    maps.save(folder)
    assert sorted(p.name for p in folder.iterdir()) == ["meta.json", "reachability.npz", "torso_height.npz"]
    np.testing.assert_array_equal(KinematicMaps.load(folder).torso_height.best_bin, maps.torso_height.best_bin)


def test_maps_config_validation() -> None:
    with pytest.raises(ValueError, match="reach_samples"):
        KinematicMapsConfig(reach_samples=0)


def test_drake_ik_collision_aware() -> None:
    from vamg_drake.robot.spheres import SphereModel

    q = layout.stow_configuration(0, 0, 0)
    q[layout.ARM] = [0.3, 0.2, 0.0, 1.0, 0.0, 0.8, 0.0]
    X = FetchKinematics.instance().gripper_pose(q)
    q_sol, ok = DrakeIk(collision_distance=0.005).solve(X, layout.stow_configuration(0, 0, 0))
    assert ok
    np.testing.assert_allclose(FetchKinematics.instance().gripper_pose(q_sol)[:3, 3], X[:3, 3], atol=2.5e-3)
    assert SphereModel.load().self_collision_free(q_sol[None])[0]


def test_decoded_reachability_is_stored_and_memory_mapped(tmp_path, caplog) -> None:
    """The first load stores the decoded arrays; later loads map them (read
    only) and give the same maps; a changed compressed file or a damaged
    decoded file is decoded again, never trusted and never a rebuild."""
    config = KinematicMapsConfig(reach_samples=20_000, torso_samples=20_000)
    maps = KinematicMaps.build(config, progress=False)
    folder = tmp_path / "maps"
    maps.save(folder)
    first = KinematicMaps.load(folder)
    assert (folder / "reachability.decoded.json").is_file()
    assert first.reachability.keys.flags.writeable  # decoded in memory this time
    mapped = KinematicMaps.load(folder)
    assert not mapped.reachability.keys.flags.writeable  # read-only pages of the stored file
    for name in ("keys", "count", "manipulability"):
        np.testing.assert_array_equal(getattr(mapped.reachability, name), getattr(first.reachability, name))
        assert type(getattr(mapped.reachability, name)) is np.ndarray
    X_BG = np.tile(np.eye(4), (5, 1, 1))
    X_BG[:, :3, 3] = [[0.6, 0.0, 0.8], [0.5, 0.2, 0.6], [0.7, -0.2, 1.0], [3.0, 0.0, 0.0], [0.4, 0.1, 0.4]]
    np.testing.assert_array_equal(mapped.capability.is_reachable(X_BG), maps.capability.is_reachable(X_BG))
    np.testing.assert_array_equal(mapped.reachability.keys, maps.reachability.keys)

    # The compressed file is rewritten (new maps): the stored arrays are stale.
    other = KinematicMaps.build(dc.replace(config, reach_samples=10_000), progress=False)
    other.save(folder)
    np.testing.assert_array_equal(KinematicMaps.load(folder).reachability.keys, other.reachability.keys)
    # A damaged stored array: decoded from the compressed file again.
    (folder / "reachability.keys.npy").write_bytes(b"garbage")
    np.testing.assert_array_equal(KinematicMaps.load(folder).reachability.keys, other.reachability.keys)
    np.testing.assert_array_equal(KinematicMaps.load(folder).reachability.keys, other.reachability.keys)
