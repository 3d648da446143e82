"""Exact identities of the discrete model (issue 2, tests 3, 4, 5)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tendonsense import lie, tendons
from tendonsense.forward import model_for, solve
from tendonsense.kinematics import grid_frames, poses


@pytest.fixture(scope="module")
def frictionless(prototype):
    return prototype.with_parameters(friction=0.0)


# each one compiled program per structure: evaluated op by op, every first call took seconds
_frames = jax.jit(grid_frames, static_argnums=0)
_actuation = jax.jit(tendons.actuation, static_argnums=0)


_lengths = jax.jit(lambda structure, values, q: tendons.length_changes(
    structure, values, poses(values, q)[0], q), static_argnums=0)


def frames(model, q):
    return _frames(model.structure, model.values, q)


def lengths(model, q):
    return _lengths(model.structure, model.values, q)


def actuation(model, q, friction):
    return _actuation(model.structure, model.values, q, friction)


def random_q(model, seed, scale=2.0):
    return jnp.asarray(np.random.default_rng(seed).normal(scale=scale, size=model.nq))


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_frictionless_actuation_is_minus_tendon_length_gradient(frictionless, seed):
    model = model_for(frictionless)
    q = random_q(model, seed)
    B = np.asarray(actuation(model, q, jnp.zeros(3)))
    dy = np.asarray(jax.jit(jax.jacfwd(lambda q: lengths(model, q)))(q))
    assert np.abs(B).max() > 1e-3
    np.testing.assert_allclose(B, -dy.T, rtol=0, atol=1e-9 * np.abs(B).max())


def test_friction_breaks_the_identity(prototype):
    """The check above can fail: with μ > 0 B is no longer a gradient."""
    model = model_for(prototype)
    q = random_q(model, 0)
    B = np.asarray(actuation(model, q, jnp.full(3, 0.4)))
    dy = np.asarray(jax.jit(jax.jacfwd(lambda q: lengths(model, q)))(q))
    assert np.abs(B + dy.T).max() > 1e-3 * np.abs(B).max()


def test_pulled_back_tendon_forces_are_body_jacobian_products(prototype):
    """B(q) as a pull-back through the poses equals ``Σ_i J_iᵀ [d_i × Rᵀf_i; Rᵀf_i]`` (eq. 13–14)
    with the body Jacobians of eq. 6, friction included."""
    model = model_for(prototype)
    q = random_q(model, 5, scale=1.0)
    grid = frames(model, q)
    unit = np.asarray(jax.jit(tendons.unit_wrenches, static_argnums=0)(
        model.structure, model.values, grid.g, jnp.full(3, 0.4)))
    B = np.zeros((model.nq, 3))
    for grp, index in zip(model.values.tendons, model.structure.groups):
        for k, j in enumerate(index):
            for node, d in zip(grp.nodes[k], grp.offsets[k]):
                f = unit[j, node, 3:]  # the body-frame force; its moment from the offset
                B[:, j] += np.asarray(grid.J[node]).T @ np.r_[np.cross(d, f), f]
    np.testing.assert_allclose(np.asarray(actuation(model, q, jnp.full(3, 0.4))), B,
                               rtol=0, atol=1e-10 * np.abs(B).max())


@pytest.mark.parametrize("seed", [3, 4])
def test_body_jacobian_matches_finite_differences_of_pose(prototype, seed):
    model = model_for(prototype)
    q = random_q(model, seed)
    grid = frames(model, q)
    eps = 1e-6
    for j in range(model.nq):
        dq = jnp.zeros(model.nq).at[j].set(eps)
        gp = frames(model, q + dq).g
        gm = frames(model, q - dq).g
        for n in range(0, len(model.values.nodes), 5):
            dg = (np.asarray(gp[n]) - np.asarray(gm[n])) / (2 * eps)
            eta = np.asarray(lie.vee(jnp.asarray(np.linalg.inv(np.asarray(grid.g[n])) @ dg)))
            np.testing.assert_allclose(np.asarray(grid.J[n][:, j]), eta, atol=1e-6)


def test_exp_and_dexp_near_zero_rotation():
    """Series and closed forms meet continuously; dexp is the derivative of exp."""
    rng = np.random.default_rng(7)
    for theta in (0.0, 1e-9, 0.0999, 0.1001, 1.3):
        w = rng.normal(size=3)
        w = theta * w / np.linalg.norm(w)
        Om = jnp.asarray(np.r_[w, rng.normal(size=3)])
        dOm = jnp.asarray(rng.normal(size=6))
        _, tangent = jax.jvp(lie.expmap, (Om,), (dOm,))
        body = lie.vee(lie.inverse(lie.expmap(Om)) @ tangent)
        expected = lie.Ad_inv(lie.expmap(Om)) @ lie.dexp(Om) @ dOm
        np.testing.assert_allclose(body, expected, atol=1e-12)


def test_basis_convergence_moves_loaded_tip_less_than_1mm(prototype):
    loads = [(0.25, (0.0, 0.2, -0.5))]
    tension = {"t1": 2.0, "t3": 1.0}
    base = solve(prototype, tension, loads)
    richer = prototype.replace(strain=tuple((m, d + 2) for m, d in prototype.strain))
    finer = solve(richer, tension, loads)
    assert base.converged and finer.converged
    moved = np.linalg.norm(base.markers["tip"] - finer.markers["tip"])
    assert moved < 1e-3
    assert np.linalg.norm(base.markers["tip"] - np.array([0.25, 0, 0])) > 0.02  # really loaded


def test_basis_derivatives_match_autodiff():
    """dΦ/dX of both bases (continuous tendons' turning rate) against autodiff in X."""
    import jax.numpy as jnp

    from tendonsense.basis import ElementsBasis, LegendreBasis
    X = np.linspace(0.001, 0.499, 37)
    for b in (LegendreBasis(0.5, {"torsion": 2, "bending_y": 4, "elongation": 3}),
              ElementsBasis((0.0, 0.1, 0.3, 0.5), {"torsion": 1, "bending_y": 3})):
        auto = jax.vmap(jax.jacfwd(lambda x: b(x[None], None, jnp)[0]))(jnp.asarray(X))
        np.testing.assert_allclose(b(X, derivative=True), auto, atol=1e-12 * np.abs(auto).max())


@pytest.mark.parametrize("elements", [False, True])
def test_pullback_is_the_transposed_body_jacobian(prototype, elements):
    """The closed-form pull-back of :func:`kinematics.configuration` (backward wrench
    recursion) against ``Σ Jᵢᵀ wᵢ`` with the body Jacobians of :func:`grid_frames`, with points
    off the grid, for both bases; also its forward-mode derivative in q and in the points' X
    (what a Newton Jacobian takes), and the custom derivative of the poses against plain
    autodiff through products of exponentials."""
    from tendonsense.kinematics import configuration, end_stretches, omega
    from tendonsense.model import points_at
    robot = prototype.replace(strain=(("torsion", 1), ("bending_y", 2), ("bending_z", 2),
                                      ("elongation", 1)),
                              elements=(0.07, 0.16)) if elements else prototype
    model = model_for(robot)
    s, v = model.structure, model.values
    q = random_q(model, 11, scale=1.5)
    X = jnp.array([0.031, 0.16, 0.2237])
    rng = np.random.default_rng(3)
    w_grid = jnp.asarray(rng.normal(size=(v.nodes.shape[0], 6)))
    c_nu = jnp.asarray(rng.normal(size=(v.h.shape[0], 2, 3)))
    w_points = jnp.asarray(rng.normal(size=(X.shape[0], 6)))

    @jax.jit  # one program each: evaluated op by op, this test took minutes
    def ours(q, X):
        return configuration(v, q, points_at(s, v, X))[1]((w_grid, c_nu, w_points))

    @jax.jit
    def theirs(q, X):
        grid, points = grid_frames(s, v, q, points_at(s, v, X))
        stretch = jax.vjp(lambda q: end_stretches(v, q), q)[1](c_nu)[0]
        return (jnp.einsum("nai,na->i", grid.J, w_grid)
                + jnp.einsum("nai,na->i", points.J, w_points) + stretch)

    expected = theirs(q, X)
    assert np.abs(expected).max() > 1e-3
    np.testing.assert_allclose(ours(q, X), expected, rtol=0,
                               atol=1e-11 * np.abs(expected).max())
    for arg in (0, 1):
        a = jax.jit(jax.jacfwd(ours, argnums=arg))(q, X)
        b = jax.jit(jax.jacfwd(theirs, argnums=arg))(q, X)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-10 * np.abs(b).max())

    def plain(q):
        p = points_at(s, v, X)
        E = jax.vmap(lie.expmap)(omega(q, v.h, v.Phi1, v.Phi2))
        G = [jnp.eye(4)]
        for e in E:
            G.append(G[-1] @ e)
        g = v.base @ jnp.stack(G)
        return g, end_stretches(v, q), g[p.start] @ jax.vmap(lie.expmap)(
            omega(q, p.h, p.Phi1, p.Phi2))

    tq = jnp.asarray(rng.normal(size=q.shape))
    a = jax.jit(lambda q: jax.jvp(lambda q: configuration(v, q, points_at(s, v, X))[0], (q,),
                                  (tq,)))(q)
    b = jax.jit(lambda q: jax.jvp(plain, (q,), (tq,)))(q)
    for x, y in zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b)):
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-11 * np.abs(y).max())


def test_residual_tension_derivative_is_exact(prototype):
    """``residual(..., with_actuation)``'s ∂r/∂T (formed from B) equals forward-mode autodiff of
    the residual in the tensions; as a predicate it is formed where the predicate holds and
    zeros elsewhere (the tracker forms it on its converged pass only)."""
    from tendonsense.statics import Drive, Unknowns, residual, scaling
    model = model_for(prototype)
    q = random_q(model, 6, scale=1.0)
    drive = Drive(jnp.array([1.5, 0.3, 0.0]), jnp.zeros((0, 3)), jnp.zeros(0),
                  jnp.array([0.0, 0.0, -9.81]), jnp.array([-0.004]))
    unknowns, sc = Unknowns.none(3), scaling(model.values, (0,))

    def r(x, T):
        return residual(model.structure, model.values, (0,), x, drive._replace(tensions=T),
                        unknowns, 1.0, sc)[0]

    exact = np.asarray(jax.jit(jax.jacfwd(r, argnums=1))(q, drive.tensions))
    rT = np.asarray(jax.jit(lambda q: residual(model.structure, model.values, (0,), q, drive,
                                               unknowns, 1.0, sc, with_actuation=True)[2])(q))
    assert np.abs(exact).max() > 1e-3
    np.testing.assert_allclose(rT, exact, rtol=0, atol=1e-12 * np.abs(exact).max())
    for holds in (True, False):
        got = jax.jit(lambda x: residual(model.structure, model.values, (0,), x, drive,
                                         unknowns, 1.0, sc,
                                         with_actuation=lambda r, s: jnp.asarray(holds))[2])(q)
        want = rT if holds else np.zeros_like(rT)
        np.testing.assert_allclose(np.asarray(got), want, rtol=0,
                                   atol=1e-12 * np.abs(exact).max() if holds else 0.0)
