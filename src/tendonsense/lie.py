"""SE(3) / se(3) utilities (paper appendix).

Twists and wrenches are ordered ``[angular; linear]``. Every function acts on a single
element; use :func:`jax.vmap` for batches. Small-angle forms are evaluated from their Taylor
series so that values *and* derivatives stay exact at zero rotation.
"""

from __future__ import annotations

import jax.numpy as jnp

_SMALL = 1e-2  # theta^2 below which the Taylor series are used (theta < 0.1)


def skew(w):
    """3-vectors (..., 3) -> skew-symmetric matrices (..., 3, 3), ``skew(a) @ b == a × b``."""
    x, y, z = w[..., 0], w[..., 1], w[..., 2]
    o = jnp.zeros_like(x)
    return jnp.stack([jnp.stack([o, -z, y], -1), jnp.stack([z, o, -x], -1),
                      jnp.stack([-y, x, o], -1)], -2)


def hat(xi):
    """se(3) twist ``[w; v]`` -> 4x4 matrix."""
    top = jnp.concatenate([skew(xi[:3]), xi[3:, None]], axis=1)
    return jnp.concatenate([top, jnp.zeros((1, 4), xi.dtype)], axis=0)


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


def dexp(Omega):
    """Tangent operator of the exponential, ``dexp_Ω = Σ_k ad_Ω^k / (k+1)!`` in closed form,
    so that ``exp(Ω)^-1 d exp(Ω) = (Ad_{exp(-Ω)} dexp_Ω dΩ)^``."""
    t2, t, small = _theta(Omega[:3])
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
    A = ad(Omega)
    A2 = A @ A
    A3 = A2 @ A
    return jnp.eye(6, dtype=Omega.dtype) + a1 * A + a2 * A2 + a3 * A3 + a4 * (A3 @ A)


def safe_norm(x):
    """Euclidean norm whose derivative at 0 is taken as 0 instead of NaN."""
    s = jnp.dot(x, x)
    pos = s > 0
    return jnp.where(pos, jnp.sqrt(jnp.where(pos, s, 1.0)), 0.0)
