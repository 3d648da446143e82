"""SE(3) / se(3) utilities (paper appendix).

Twists and wrenches are ordered ``[angular; linear]``. The matrix-valued functions act on a
single element (use :func:`jax.vmap` for batches); the ``*_apply`` operators act on batches
(leading axes) as matrix-vector products, without forming the 6x6 matrices. Small-angle forms
are evaluated from their Taylor series so that values *and* derivatives stay exact at zero
rotation.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax.custom_derivatives import SymbolicZero

_SMALL = 1e-2  # theta^2 below which the Taylor series are used (theta < 0.1)


def skew(w):
    """3-vectors (..., 3) -> skew-symmetric matrices (..., 3, 3), ``skew(a) @ b == a × b``."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1),
                      jnp.stack([-y, x, o], -1)], -2)


def vee(m):
    """4x4 se(3) matrix -> twist ``[w; v]``."""
    return jnp.array([m[2, 1], m[0, 2], m[1, 0], m[0, 3], m[1, 3], m[2, 3]])


def ad(xi):
    """Adjoint operator of se(3): ``ad_xi = [[w~, 0], [v~, w~]]``."""
    w, v = skew(xi[:3]), skew(xi[3:])
    zero = jnp.zeros((3, 3), xi.dtype)
    return jnp.block([[w, zero], [v, w]])


def Ad(g):
    """Adjoint map of SE(3): ``Ad_g = [[R, 0], [r~ R, R]]``."""
    R, r = g[:3, :3], g[:3, 3]
    zero = jnp.zeros((3, 3), g.dtype)
    return jnp.block([[R, zero], [skew(r) @ R, R]])


def Ad_inv(g):
    """``Ad_{g^-1} = [[R^T, 0], [-R^T r~, R^T]]``."""
    R, r = g[:3, :3], g[:3, 3]
    Rt = R.T
    zero = jnp.zeros((3, 3), g.dtype)
    return jnp.block([[Rt, zero], [-Rt @ skew(r), Rt]])


def inverse(g):
    """Inverse of a homogeneous transform."""
    R, r = g[:3, :3], g[:3, 3]
    top = jnp.concatenate([R.T, (-R.T @ r)[:, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], g.dtype)], axis=0)


def _theta(w):
    """(theta^2, theta, small) with a theta that is safe to divide by and differentiate."""
    t2 = jnp.dot(w, w)
    small = t2 < _SMALL
    t = jnp.sqrt(jnp.where(small, 1.0, t2))
    return t2, t, small


def expmap(Omega):
    """Exponential map se(3) -> SE(3) (appendix):
    ``exp(Ω^) = I + Ω^ + (1 - cos θ)/θ² Ω^² + (θ - sin θ)/θ³ Ω^³``, θ = |Ω_w|, in the
    equivalent Rodrigues form ``R = I + (1 − θ² c2) w~ + c1 w~²``, ``p = (I + c1 w~ + c2 w~²) v``."""
    w, v = Omega[:3], Omega[3:]
    t2, t, small = _theta(w)
    c1 = jnp.where(small, 1 / 2 - t2 / 24 + t2**2 / 720 - t2**3 / 40320 + t2**4 / 3628800,
                   (1 - jnp.cos(t)) / t**2)
    c2 = jnp.where(small, 1 / 6 - t2 / 120 + t2**2 / 5040 - t2**3 / 362880 + t2**4 / 39916800,
                   (t - jnp.sin(t)) / t**3)
    W = skew(w)
    R = (1 - c1 * t2) * jnp.eye(3, dtype=Omega.dtype) + (1 - t2 * c2) * W + c1 * jnp.outer(w, w)
    wv = jnp.cross(w, v)
    p = v + c1 * wv + c2 * jnp.cross(w, wv)
    top = jnp.concatenate([R, p[:, None]], axis=1)
    return jnp.concatenate([top, jnp.array([[0.0, 0.0, 0.0, 1.0]], Omega.dtype)], axis=0)


def _dexp_coefficients(Omega):
    """``a1..a4`` of ``dexp_Ω = I + a1 ad + a2 ad² + a3 ad³ + a4 ad⁴`` (batched, θ = |Ω_w|)."""
    t2 = jnp.sum(Omega[..., :3] ** 2, axis=-1)
    small = t2 < _SMALL
    t = jnp.sqrt(jnp.where(small, 1.0, t2))
    s, c = jnp.sin(t), jnp.cos(t)
    a1 = jnp.where(small, 1 / 2 - t2**2 / 720 + t2**3 / 20160 - t2**4 / 1209600,
                   (4 - 4 * c - t * s) / (2 * t**2))
    a2 = jnp.where(small, 1 / 6 - t2**2 / 5040 + t2**3 / 181440 - t2**4 / 13305600,
                   (4 * t - 5 * s + t * c) / (2 * t**3))
    a3 = jnp.where(small, 1 / 24 - t2 / 360 + t2**2 / 13440 - t2**3 / 907200 + t2**4 / 95800320,
                   (2 - 2 * c - t * s) / (2 * t**4))
    a4 = jnp.where(small, 1 / 120 - t2 / 2520 + t2**2 / 120960 - t2**3 / 9979200
                   + t2**4 / 1245404160,
                   (2 * t - 3 * s + t * c) / (2 * t**5))
    return a1, a2, a3, a4


def dexp(Omega):
    """Tangent operator of the exponential, ``dexp_Ω = Σ_k ad_Ω^k / (k+1)!`` in closed form,
    so that ``exp(Ω)^-1 d exp(Ω) = (Ad_{exp(-Ω)} dexp_Ω dΩ)^``."""
    a1, a2, a3, a4 = _dexp_coefficients(Omega)
    A = ad(Omega)
    A2 = A @ A
    A3 = A2 @ A
    return jnp.eye(6, dtype=Omega.dtype) + a1 * A + a2 * A2 + a3 * A3 + a4 * (A3 @ A)


def ad_apply(xi, u, transpose=False):
    """``ad_ξ u`` (or ``ad_ξᵀ u``), batched: ``[w × m; v × m + w × f]`` for ξ = [w; v],
    u = [m; f] (transposed: ``[−w × m − v × f; −w × f]``)."""
    w, v, m, f = xi[..., :3], xi[..., 3:], u[..., :3], u[..., 3:]
    if transpose:
        return jnp.concatenate([-jnp.cross(w, m) - jnp.cross(v, f), -jnp.cross(w, f)], -1)
    return jnp.concatenate([jnp.cross(w, m), jnp.cross(v, m) + jnp.cross(w, f)], -1)


def pointwise(f, linear=()):
    """``f`` of batches (arrays (..., k), the same leading axes, acting on each element alone)
    with its forward-mode derivative as one small Jacobian per element (found by as many
    passes as the element has components) applied to the tangents: cheaper than carrying
    many tangents through every operation of ``f``. In the arguments ``linear``, f is linear:
    their tangent term is f itself, applied to the tangent."""

    @jax.custom_jvp
    def g(*args):
        return f(*args)

    def rule(primals, tangents):
        out, d_out = f(*primals), None
        for i, (x, dx) in enumerate(zip(primals, tangents)):
            if isinstance(dx, SymbolicZero):
                continue
            if i in linear:
                term = f(*primals[:i], dx, *primals[i + 1:])
            else:
                def along(e, i=i):
                    return jax.jvp(lambda y: f(*primals[:i], y, *primals[i + 1:]), (x,), (e,))[1]
                basis = jnp.broadcast_to(jnp.eye(x.shape[-1], dtype=x.dtype)[:, None],
                                         (x.shape[-1],) + x.shape)
                columns = jax.vmap(along)(basis)  # (k, ..., n_out)
                # unrolled: a loop fusion, not a batch of tiny matrix products
                term = sum(columns[k] * dx[..., k, None] for k in range(x.shape[-1]))
            d_out = term if d_out is None else d_out + term
        return out, jnp.zeros_like(out) if d_out is None else d_out

    g.defjvp(rule, symbolic_zeros=True)
    return g


def dexp_apply(Omega, v, transpose=False):
    """``dexp_Ω v`` (or ``dexp_Ωᵀ v``), batched, by Horner's scheme in ad_Ω."""
    return (_dexp_T_apply if transpose else _dexp_apply)(Omega, v)


def _horner(Omega, v, transpose):
    a = _dexp_coefficients(Omega)
    out = a[3][..., None] * ad_apply(Omega, v, transpose)
    for c in a[2::-1]:
        out = ad_apply(Omega, c[..., None] * v + out, transpose)
    return v + out


_dexp_apply = pointwise(lambda Omega, v: _horner(Omega, v, False), linear=(1,))
_dexp_T_apply = pointwise(lambda Omega, v: _horner(Omega, v, True), linear=(1,))


def rotate(R, x):
    """``R x`` for rotations R (..., 3, 3) and vectors x (..., 3), batched. Written as products
    and a sum, not ``einsum``: XLA's classic CPU emitter (:func:`tendonsense.settings.
    compiler_options`) makes a batch of 3×3 products one small matrix product each, a loop
    fusion does them all at once (the residual of the paper's prototype 21 → 11 µs)."""
    return jnp.sum(R * x[..., None, :], axis=-1)


def rotate_T(R, x):
    """``Rᵀ x``, batched (as :func:`rotate`)."""
    return jnp.sum(R * x[..., :, None], axis=-2)


def Ad_apply(g, eta):
    """``Ad_g η`` for poses g (..., 4, 4): ``[R w; r × R w + R v]``."""
    R, r = g[..., :3, :3], g[..., :3, 3]
    Rw, Rv = rotate(R, eta[..., :3]), rotate(R, eta[..., 3:])
    return jnp.concatenate([Rw, jnp.cross(r, Rw) + Rv], -1)


def coAd_apply(g, w):
    """``Ad_{g⁻¹}ᵀ w``: a wrench w = [m; f] in the frame g, in the frame g is given in:
    ``[R m + r × R f; R f]``."""
    R, r = g[..., :3, :3], g[..., :3, 3]
    Rm, Rf = rotate(R, w[..., :3]), rotate(R, w[..., 3:])
    return jnp.concatenate([Rm + jnp.cross(r, Rf), Rf], -1)


def Ad_T_apply(g, w):
    """``Ad_gᵀ w``, the inverse of :func:`coAd_apply`: ``[Rᵀ(m − r × f); Rᵀ f]``."""
    R, r = g[..., :3, :3], g[..., :3, 3]
    m, f = w[..., :3], w[..., 3:]
    return jnp.concatenate([rotate_T(R, m - jnp.cross(r, f)), rotate_T(R, f)], -1)


def hat_times(sigma, g):
    """``σ^ g`` for twists σ and poses g, batched (the derivative of g along a spatial
    twist)."""
    w, v = sigma[..., :3], sigma[..., 3:]
    R, r = g[..., :3, :3], g[..., :3, 3]
    top = jnp.concatenate([jnp.cross(w[..., :, None], R, axis=-2),
                           (jnp.cross(w, r) + v)[..., None]], -1)
    return jnp.concatenate([top, jnp.zeros_like(g[..., 3:, :])], -2)


def safe_norm(x, xp=jnp):
    """Euclidean norms over the last axis, whose derivative at 0 is taken as 0 instead of
    NaN (``xp`` numpy: on the host, no program to build)."""
    s = xp.sum(x * x, axis=-1)
    pos = s > 0
    return xp.where(pos, xp.sqrt(xp.where(pos, s, 1.0)), 0.0)
