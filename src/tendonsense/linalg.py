"""Dense factorisations and solves inside compiled programs, in XLA's own operations.

The solvers' programs call no LAPACK kernel: a kept executable that calls one makes every
process that loads it import SciPy's LAPACK first (0.2–0.3 s of a warm start-up), and XLA's
CPU triangular solve with a matrix right-hand side is slow for the sizes of an elements
basis (about 12 ms for 72 × 72, where an LU factorisation takes 0.05 ms). So these factorise
column by column and substitute row by row (loops of n rank-one or vector steps; the
systems here have at most a few hundred unknowns)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def _substitute(T, B, lower: bool):
    """``T⁻¹ B`` for a triangular T (its other triangle ignored), B (n,) or (n, k)."""
    T, B = jnp.asarray(T), jnp.asarray(B)
    n = T.shape[0]
    T = jnp.tril(T) if lower else jnp.triu(T)

    def row(X, i):
        # rows of X not yet solved are zero, so T[i] @ X holds only the solved ones
        return X.at[i].set((B[i] - T[i] @ X) / T[i, i]), None

    order = jnp.arange(n) if lower else jnp.arange(n - 1, -1, -1)
    return jax.lax.scan(row, jnp.zeros_like(B), order)[0]


def lu(A):
    """LU with partial pivoting, ``A[perm] = L U``: ``(lu, perm, sign)`` with L's strict lower
    triangle (unit diagonal) and U in ``lu``, and the permutation's sign. A zero pivot gives
    non-finite entries, as LAPACK's ``getrf`` leaves a singular matrix unsolvable."""
    A = jnp.asarray(A)
    n = A.shape[0]
    index = jnp.arange(n)

    def column(k, carry):
        a, perm, sign = carry
        p = jnp.argmax(jnp.where(index >= k, jnp.abs(a[:, k]), -1.0))
        swap = jnp.where(index == k, p, jnp.where(index == p, k, index))
        a, perm = a[swap], perm[swap]
        below = index > k
        l = jnp.where(below, a[:, k] / a[k, k], 0.0)
        a = a - jnp.outer(l, jnp.where(below, a[k], 0.0))
        return a.at[:, k].set(jnp.where(below, l, a[:, k])), perm, jnp.where(p == k, sign, -sign)

    return jax.lax.fori_loop(0, n, column, (A, index, jnp.asarray(1.0, A.dtype)))


def cholesky(A):
    """The lower-triangular L with ``A = L Lᵀ`` of a symmetric positive definite A (its upper
    triangle ignored); NaN where A is not positive definite."""
    A = jnp.asarray(A)
    n = A.shape[0]
    index = jnp.arange(n)

    def column(j, L):
        # columns j and after are still zero, so L @ L[j] sums over the ones done
        c = A[:, j] - L @ L[j]
        d = jnp.sqrt(c[j])
        return L.at[:, j].set(jnp.where(index > j, c / d, jnp.where(index == j, d, 0.0)))

    return jax.lax.fori_loop(0, n, column, jnp.zeros_like(A))


def solve(A, B):
    """``A⁻¹ B`` (B of shape (n,) or (n, k)) by LU with partial pivoting."""
    A, B = jnp.asarray(A), jnp.asarray(B)
    factors, perm, _ = lu(A)
    unit = jnp.tril(factors, -1) + jnp.eye(A.shape[0], dtype=factors.dtype)
    return _substitute(factors, _substitute(unit, B[perm], lower=True), lower=False)


def inv(A):
    """``A⁻¹`` by LU with partial pivoting."""
    return solve(A, jnp.eye(A.shape[0], dtype=A.dtype))


def det(A):
    """The determinant, from the LU factors."""
    factors, _, sign = lu(A)
    return sign * jnp.prod(jnp.diagonal(factors))


def lower_inverse(L):
    """``L⁻¹`` of a lower-triangular L."""
    return _substitute(L, jnp.eye(L.shape[0], dtype=L.dtype), lower=True)
