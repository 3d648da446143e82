"""Classic tendon-driven continuum robots (issue 16): spacer disks wider than the backbone
and continuously routed tendons, against a peer's published solution, the disk model's limit
and the independent BVP."""

import numpy as np
import pytest

from conftest import ROOT
from cosserat_bvp import CosseratBVP
from tendonsense.forward import forward_kinematics, model_for, solve
from tendonsense.robot import RobotFileError, load_robot, robot_to_toml

PEER = ROOT / "examples" / "spacer_disk_robot.toml"
#: the peer's shooting solution (Till & Rucker's continuum-robot statics examples): the tip
#: with 15 N on the tendon on the +x side, gravity along +x, mm
PEER_TIP = np.array([182.212, 0.0, 453.229])


@pytest.fixture(scope="module")
def peer():
    return load_robot(PEER)


def with_tendons(robot, disks=None, friction=None):
    """The robot with every tendon's disks (a count, or "continuous") and μ replaced."""
    tendons = []
    for t in robot.tendons:
        if disks is not None:
            X = (0.0, robot.rod.length) if disks == "continuous" else tuple(
                np.linspace(0.0, robot.rod.length, disks))
            t = t.__class__(t.name, t.offset_base, t.offset_tip, t.friction, X,
                            disks == "continuous")
        if friction is not None:
            t = t.__class__(t.name, t.offset_base, t.offset_tip, friction, t.disks, t.continuous)
        tendons.append(t)
    return robot.replace(tendons=tuple(tendons))


def test_the_peer_robot_file_and_its_checks(peer, tmp_path):
    assert peer.rod.disk_radius == pytest.approx(0.016)
    assert all(t.continuous for t in peer.tendons)
    again = tmp_path / "again.toml"
    again.write_text(robot_to_toml(peer))
    assert load_robot(again) == peer
    text = PEER.read_text()
    (tmp_path / "no_disks.toml").write_text(text.replace("disk_radius = 0.016\n", ""))
    with pytest.raises(RobotFileError) as e:
        load_robot(tmp_path / "no_disks.toml")
    msg = str(e.value)
    assert "rod.disk_radius" in msg and "reachable radius" in msg
    assert " X = " not in msg  # the offset is the same all along the rod: no X to blame
    (tmp_path / "narrow.toml").write_text(text.replace("disk_radius = 0.016", "disk_radius = 0.015"))
    with pytest.raises(RobotFileError, match="beyond the spacer disks"):
        load_robot(tmp_path / "narrow.toml")
    (tmp_path / "thin.toml").write_text(text.replace("disk_radius = 0.016", "disk_radius = 0.0005"))
    with pytest.raises(RobotFileError, match="rod.disk_radius: spacer disks"):
        load_robot(tmp_path / "thin.toml")
    (tmp_path / "mm.toml").write_text(text.replace("disk_radius = 0.016", "disk_radius = 16"))
    with pytest.raises(RobotFileError, match=r"rod.disk_radius: 16 m is more than half the rod's "
                                             r"length .*lengths are in metres"):
        load_robot(tmp_path / "mm.toml")  # mm typed (was accepted: disks 16 m wide)
    (tmp_path / "bad.toml").write_text(text.replace('disks = "continuous"', 'disks = "spiral"', 1))
    with pytest.raises(RobotFileError, match='disks: must be a count, a list of X or "continuous"'):
        load_robot(tmp_path / "bad.toml")


def test_continuous_routing_meets_the_peers_tip_and_the_disk_model_converges_to_it(peer):
    tip = solve(peer, {"t1": 15.0}).backbone[-1] * 1e3
    assert np.linalg.norm(tip - PEER_TIP) < 0.01, tip
    errors = []
    for n in (21, 41, 81):
        res = solve(with_tendons(peer, n), {"t1": 15.0})
        assert res.converged
        errors.append(np.linalg.norm(res.backbone[-1] * 1e3 - tip))
    ratios = np.array(errors[:-1]) / np.array(errors[1:])
    assert np.all(np.abs(ratios - 4.0) < 0.4), (errors, ratios)  # 1/n² (n − 1 intervals)


@pytest.mark.parametrize("friction", [0.0, 0.25])
def test_continuous_routing_against_the_independent_bvp(peer, friction):
    """Tip position and tendon lengths, 15 N on one tendon and 5 N on another, with and
    without Capstan friction on the turning of the path."""
    robot = with_tendons(peer, friction=friction)
    T = (15.0, 5.0, 0.0, 0.0)
    reference = CosseratBVP(robot, T, shear=False).solve()
    gvs = solve(robot, dict(zip(robot.tendon_names, T)))
    assert gvs.converged
    assert np.linalg.norm(gvs.markers["tip"] - reference.markers()["tip"]) < 1e-6
    for name, y in reference.tendon_length_changes().items():
        assert gvs.displacements[name] == pytest.approx(y, abs=1e-7), name
    if friction:  # friction really changes the shape
        plain = solve(with_tendons(peer, friction=0.0), dict(zip(robot.tendon_names, T)))
        assert np.linalg.norm(plain.markers["tip"] - gvs.markers["tip"]) > 1e-3


def test_gravity_alone_against_the_bvp(peer):
    reference = CosseratBVP(peer, (0.0,) * 4, shear=False).solve().markers()["tip"]
    assert np.linalg.norm(solve(peer, {}).markers["tip"] - reference) < 1e-6


def test_continuous_tendons_in_the_inverse_problems(peer):
    """Tendon-length forward kinematics, estimation (a tip force) and the identity
    B = −(∂y/∂q)ᵀ without friction."""
    import jax

    from tendonsense import tendons
    from tendonsense.estimation import PointForceUnknown, estimate
    from tendonsense.kinematics import poses

    model = model_for(peer)
    q = np.random.default_rng(0).normal(scale=0.5, size=model.nq)
    # each side one compiled program: evaluated op by op, these took 52 s instead of 9 s
    B = np.asarray(jax.jit(lambda q: tendons.actuation(model.structure, model.values, q,
                                                       model.values.friction))(q))
    dy = np.asarray(jax.jit(jax.jacfwd(lambda q: tendons.length_changes(
        model.structure, model.values, poses(model.values, q)[0], q)))(q))
    np.testing.assert_allclose(B, -dy.T, atol=1e-12 * np.abs(B).max())

    # the analytic derivatives of the continuous tendons' forces (in q and μ) against plain
    # forward-mode autodiff through the same forces
    rough = with_tendons(peer, friction=0.2)
    m = model_for(rough)
    mu = np.asarray(m.values.friction)
    exact = jax.jit(jax.jacfwd(lambda q, mu: tendons.continuous_actuation(
        m.structure, m.values, q, mu), argnums=(0, 1)))(q, mu)
    plain = jax.jit(jax.jacfwd(lambda q, mu: tendons._continuous(
        q, mu, m.values.continuous, m.values.h)[0].T, argnums=(0, 1)))(q, mu)
    for a, b in zip(exact, plain):
        np.testing.assert_allclose(a, b, atol=1e-12 * np.abs(b).max())
    # without friction the turning angle is skipped: the same derivative in q
    assert not np.any(model.values.friction)
    exact = jax.jit(jax.jacfwd(lambda q: tendons.continuous_actuation(
        model.structure, model.values, q, model.values.friction)))(q)
    plain = jax.jit(jax.jacfwd(lambda q: tendons._continuous(
        q, model.values.friction, model.values.continuous, model.values.h)[0].T))(q)
    np.testing.assert_allclose(exact, plain, atol=1e-12 * np.abs(plain).max())

    f = (0.0, 0.3, -0.5)
    truth = solve(rough, {"t1": 15.0, "t2": 4.0}, [(0.5, f)])
    fk = forward_kinematics(rough, {"t1": truth.displacements["t1"]}, {"t2": 4.0}, [(0.5, f)])
    assert fk.converged and fk.tensions["t1"] == pytest.approx(15.0, rel=1e-8)
    est = estimate(rough, {n: truth.displacements[n] for n in ("t1", "t2", "t3")},
                   {"t1": 15.0, "t2": 4.0, "t3": 0.0}, [PointForceUnknown(0.5, f)])
    assert est.converged and est.magnitudes[0] == pytest.approx(np.linalg.norm(f), rel=1e-6)


def test_continuous_tendons_in_logs_and_calibration(peer):
    """The fast path over a log (a tip force growing while t1 is pulled) and a camera-free
    calibration of E from the tendons' readings."""
    from tendonsense.estimation import PointForceUnknown, problem
    from tendonsense.identification import Snapshot, identify
    from tendonsense.tracking import estimate_series

    rough = with_tendons(peer, friction=0.2)
    F = np.linspace(0.1, 0.5, 6)
    disp, ten = [], []
    for k, f in enumerate(F):
        T = {"t1": 10.0 + k, "t2": 3.0, "t3": 0.0}
        res = solve(rough, T, [(0.5, (0.0, 0.0, -f))])
        disp.append({n: res.displacements[n] for n in ("t1", "t2", "t3")})
        ten.append(T)
    prob = problem(rough, ["t1", "t2", "t3"], [PointForceUnknown(0.5, (0.0, 0.0, -1.0))])
    out = estimate_series(prob, disp, ten, chunk=4)
    assert all(s.converged for s in out)
    np.testing.assert_allclose([s.magnitudes[0] for s in out], F, rtol=1e-6)

    snaps = [Snapshot(T, {}, None, solve(rough, T).displacements)
             for T in ({}, {"t1": 8.0}, {"t1": 15.0, "t2": 5.0})]
    fit = identify(rough.with_parameters(young_modulus=150e9), snaps, ["young_modulus"],
                   length_noise=1e-5)
    assert fit.converged and fit.parameters["young_modulus"] == pytest.approx(200e9, rel=1e-5)
