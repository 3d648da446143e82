"""An independent Cosserat-rod boundary-value solver (test suite only).

Full Kirchhoff–Cosserat statics with shear and extension, integrated in the global frame
(Antman; Rucker & Webster 2011):

    r' = R v,  R' = R û,  n' = −ρ A a_g,  m' = −r' × n,
    v = e_x + diag(EA, GA, GA)⁻¹ Rᵀ n,   u = diag(G Jx, E Jy, E Jz)⁻¹ Rᵀ m,

with the orientation as a unit quaternion. Continuously routed tendons (Rucker & Webster
2011) enter through the composite section: ``n`` and ``m`` are then the internal force and
moment of rod and tendons together (``n' = −ρ A a_g`` and ``m' = −r' × n`` still hold, a
tendon's tension acting along its own path), the rod's part is ``n − Σ τ t`` and
``m − Σ (R d) × τ t`` with t the tendon path's tangent, solved pointwise by fixed-point
iteration; Capstan friction fades τ with the path's turning angle, found by Picard iteration
on the tension profile (a BVP solve per iteration). Point forces (tendon disks, point loads) make
``n`` and ``m`` jump. The rod is split at every disk, marker and load into segments that share
one normalised abscissa, so that ``scipy.integrate.solve_bvp`` solves all of them at once with
the jumps — which depend on the neighbouring disk positions through the tendon path and the
Capstan law of SPEC §2 — written as boundary conditions. Nothing here uses tendonsense's
kinematics, strain basis or solver; only the robot description is shared.
"""

from __future__ import annotations

import numpy as np
from scipy.integrate import solve_bvp


def quat_to_rot(Q):
    """(4, m) unit quaternions [w, x, y, z] -> (m, 3, 3)."""
    Q = Q / np.linalg.norm(Q, axis=0)
    w, x, y, z = Q
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def _angle(a, b):
    """Angles between unit vectors (rows), accurate for small angles."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _cross(a, b):
    """a × b of two 3-vectors (``np.cross``'s arithmetic, without its overhead)."""
    return np.array([a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                     a[0] * b[1] - a[1] * b[0]])


def rot_to_quat(R):
    w = np.sqrt(max(1e-300, 1 + np.trace(R))) / 2
    return np.array([w, (R[2, 1] - R[1, 2]) / (4 * w), (R[0, 2] - R[2, 0]) / (4 * w),
                     (R[1, 0] - R[0, 1]) / (4 * w)])


class CosseratBVP:
    """The robot with tensions ``T`` (per tendon), point loads [(X, f)] and its gravity.
    ``held`` {tendon index: tensions of its segments between disks (N)}: those tendons stick
    and slip disk by disk — a segment keeps its tension unless the ratio across its disk would
    leave the Capstan band ``[exp(−μφ), exp(+μφ)]``, where it slides to the band's edge
    (:meth:`segment_tensions` gives the next step's ``held``)."""

    def __init__(self, robot, tensions, point_forces=(), shear: bool = True, held=None):
        self.robot = robot
        self.held = held or {}
        self.shear = shear  # False: shear held rigid (like a GVS basis without shear modes)
        rod = robot.rod
        self.L = rod.length
        self.E, self.G = rod.young_modulus, rod.young_modulus / (2 * (1 + rod.poisson_ratio))
        self.rho = rod.density
        self.a_g = np.array(robot.gravity, float)
        self.T = np.asarray(tensions, float)
        self.loads = [(float(X), np.asarray(f, float)) for X, f in point_forces]
        cuts = {0.0, self.L, *(m.X for m in robot.markers), *(X for X, _ in self.loads)}
        for t in robot.tendons:
            cuts |= set(t.disks)
        self.cuts = np.array(sorted(cuts))
        self.nseg = len(self.cuts) - 1
        self.R0 = np.array(robot.base_rotation)
        self.p0 = np.array(robot.base_position)
        # continuous tendons under tension: (index, offset d, d′); their tension profile
        self.routed = [(j, t) for j, t in enumerate(robot.tendons)
                       if t.continuous and self.T[j] != 0]
        self.fade = [lambda X: np.ones_like(X) for _ in self.routed]  # τ / T along the rod
        self.remesh = None  # see :meth:`solve`

    def _radius(self, X):
        return self.robot.rod.radius(X)

    def ode(self, s, y, lam):
        out = np.empty_like(y)
        for k in range(self.nseg):
            a, b = self.cuts[k], self.cuts[k + 1]
            X = a + s * (b - a)
            Y = y[13 * k:13 * k + 13]
            Q, n, m = Y[3:7], Y[7:10], Y[10:13]  # r does not enter the equations
            R = quat_to_rot(Q)
            rad = self._radius(X)
            A, I = np.pi * rad**2, np.pi * rad**4 / 4
            v, u = self._strains(X, R, n, m, A, I, lam)
            dr = np.einsum("mij,jm->im", R, v)
            w, x, yq, z = Q / np.linalg.norm(Q, axis=0)
            ux, uy, uz = u
            dQ = 0.5 * np.array([-x * ux - yq * uy - z * uz, w * ux + yq * uz - z * uy,
                                 w * uy + z * ux - x * uz, w * uz + x * uy - yq * ux])
            dn = -lam * self.rho * A * self.a_g[:, None]
            dm = -np.cross(dr.T, n.T).T
            out[13 * k:13 * k + 13] = (b - a) * np.concatenate([dr, dQ, dn, dm])
        return out

    def ode_jacobian(self, s, y, lam):
        """∂ode/∂y (n, n, points) by forward differences, as ``solve_bvp`` estimates it (same
        steps, the same numbers), perturbing one component of every segment at once: a
        segment's equations involve its own state only, so the Jacobian is block-diagonal
        and 13 evaluations give it, not 13 per segment."""
        f0 = self.ode(s, y, lam)
        J = np.zeros((y.shape[0], y.shape[0], y.shape[1]))
        h = np.finfo(float).eps ** 0.5 * (1 + np.abs(y))
        for i in range(13):
            rows = np.arange(i, y.shape[0], 13)
            y_new = y.copy()
            y_new[rows] += h[rows]
            df = self.ode(s, y_new, lam) - f0
            for k, j in enumerate(rows):
                J[13 * k:13 * k + 13, j] = df[13 * k:13 * k + 13] / (y_new[j] - y[j])
        return J

    def _strains(self, X, R, n, m, A, I, lam):
        """v and u (body frame, (3, points)) from the section's total n and m (global)."""
        n_loc = np.einsum("mji,jm->im", R, n)
        m_loc = np.einsum("mji,jm->im", R, m)
        stiff_n = np.array([self.E * A, self.G * A, self.G * A])
        stiff_m = np.array([self.G * 2 * I, self.E * I, self.E * I])
        v = np.array([1.0, 0, 0])[:, None] + n_loc / stiff_n
        u = m_loc / stiff_m
        if not self.shear:
            v[1:] = 0.0
        if not self.routed:
            return v, u
        for _ in range(200):  # the tendons' share depends on the strains through t
            n_rod, m_rod = n_loc.copy(), m_loc.copy()
            for (j, t), fade in zip(self.routed, self.fade):
                d = t.offset(X, self.L).T
                w = v + np.cross(u.T, d.T).T + (t.offset(self.L, self.L)[0]
                                                - t.offset(0.0, self.L)[0])[:, None] / self.L
                pull = lam * self.T[j] * fade(X) * w / np.linalg.norm(w, axis=0)
                n_rod -= pull
                m_rod -= np.cross(d.T, pull.T).T
            v_new = np.array([1.0, 0, 0])[:, None] + n_rod / stiff_n
            if not self.shear:
                v_new[1:] = 0.0
            u_new = m_rod / stiff_m
            change = max(np.abs(v_new - v).max(), np.abs(u_new - u).max() * self.L)
            v, u = v_new, u_new
            if change < 1e-14:
                return v, u
        raise RuntimeError("reference BVP: the tendons' share of the section did not converge")

    def _frames_at_cuts(self, ya, yb):
        """Position and rotation at every cut (from the segment starting there, or ending)."""
        Y = np.concatenate([ya.reshape(self.nseg, 13), yb[None, 13 * (self.nseg - 1):]])
        return list(zip(Y[:, :3], quat_to_rot(Y[:, 3:7].T)))

    def point_forces_at_cuts(self, frames, lam, record=None):
        """Global force and moment (about the centre line) applied at every cut; ``record``
        (a dict) receives every disk tendon's segment tensions."""
        F = np.zeros((self.nseg + 1, 3))
        M = np.zeros((self.nseg + 1, 3))
        cut_index = {x: i for i, x in enumerate(self.cuts)}
        for j, t in enumerate(self.robot.tendons):
            if self.T[j] == 0 or t.continuous:
                continue
            idx = [cut_index[x] for x in t.disks]
            d = t.offset(np.array(t.disks), self.L)
            pts = [frames[c][0] + frames[c][1] @ d[i] for i, c in enumerate(idx)]
            nd = len(idx)
            tension = lam * self.T[j]
            for i in range(nd):
                if i == 0:
                    vL = -frames[idx[0]][1][:, 0]
                else:
                    vL = pts[i - 1] - pts[i]
                    vL /= np.linalg.norm(vL)
                if i < nd - 1:
                    vR = pts[i + 1] - pts[i]
                    vR /= np.linalg.norm(vR)
                    phi = np.arccos(np.clip(-vL @ vR, -1.0, 1.0))
                    after = tension * np.exp(-t.friction * phi)
                    if j in self.held:
                        after = np.clip(lam * self.held[j][i], after,
                                        tension * np.exp(t.friction * phi))
                    if record is not None:
                        record.setdefault(j, []).append(after)
                else:
                    vR, after = np.zeros(3), 0.0
                f = tension * vL + after * vR
                c = idx[i]
                F[c] += f
                M[c] += _cross(frames[c][1] @ d[i], f)
                tension = after
        for X, f in self.loads:
            F[cut_index[X]] += lam * f
        return F, M

    def bc(self, ya, yb, lam):
        res = [ya[0:3] - self.p0, ya[3:7] - rot_to_quat(self.R0)]
        F, M = self.point_forces_at_cuts(self._frames_at_cuts(ya, yb), lam)
        for k in range(self.nseg - 1):
            end, start = yb[13 * k:13 * k + 13], ya[13 * (k + 1):13 * (k + 2)]
            c = k + 1
            res += [end[:7] - start[:7], end[7:10] - (start[7:10] + F[c]),
                    end[10:13] - (start[10:13] + M[c])]
        tip = yb[13 * (self.nseg - 1):]
        res += [tip[7:10] - F[-1], tip[10:13] - M[-1]]
        return np.concatenate(res)

    def solve(self, steps=(0.25, 0.5, 0.75, 1.0), nodes=11, tol=1e-7, picard=30,
              remesh: int | None = None):
        """Load steps, then (continuous tendons with friction) Picard iterations on their
        tension profiles until the tip moves less than 1e-10 m. ``remesh``: each load step
        starts from the last one's solution on that many uniform nodes (None: on the last
        one's mesh, which each step only refines; over many steps it can outgrow memory)."""
        self.remesh = remesh
        self._solve(steps, nodes, tol)
        if not any(t.friction for _, t in self.routed):
            return self
        tip = self.position(self.L)
        for _ in range(picard):
            fades = []
            for j, t in self.routed:
                X, theta = self.turning_angle(t)
                fades.append(lambda x, X=X, f=np.exp(-t.friction * theta): np.interp(x, X, f))
            self.fade = fades
            self._solve((1.0,), nodes, tol, warm=True)
            new_tip = self.position(self.L)
            if np.linalg.norm(new_tip - tip) < 1e-10:
                return self
            tip = new_tip
        raise RuntimeError("reference BVP: the friction tension profile did not converge")

    def turning_angle(self, t, n=4001):
        """The angle a continuous tendon's path has turned through from the actuator (arriving
        along the base's x axis) to X: the path's tangent ``R (v + u × d + d′)`` from the
        solution's strains on a fine grid, the angles between neighbours summed."""
        X = np.linspace(0.0, self.L, n)
        tangents = []
        for k in range(self.nseg):
            a, b = self.cuts[k], self.cuts[k + 1]
            inside = (X >= a) & ((X < b) | (k == self.nseg - 1))
            Xs = X[inside]
            Y = self.solution.sol((Xs - a) / (b - a))[13 * k:13 * k + 13]
            R = quat_to_rot(Y[3:7])
            rad = self._radius(Xs)
            v, u = self._strains(Xs, R, Y[7:10], Y[10:13], np.pi * rad**2, np.pi * rad**4 / 4,
                                 1.0)
            slope = (t.offset(self.L, self.L)[0] - t.offset(0.0, self.L)[0]) / self.L
            w = v + np.cross(u.T, t.offset(Xs, self.L)).T + slope[:, None]
            tangents.append(np.einsum("mij,jm->mi", R, w / np.linalg.norm(w, axis=0)))
        tangent = np.concatenate(tangents)
        first = _angle(tangent[:1], self.R0[:, 0])[0]
        turns = _angle(tangent[1:], tangent[:-1])
        return X, first + np.concatenate([[0.0], np.cumsum(turns)])

    def segment_tensions(self) -> dict[int, np.ndarray]:
        """The tension of every segment between disks of every tensioned disk tendon (N)."""
        record = {}
        self.point_forces_at_cuts(self._frames_at_cuts(
            *(self.solution.sol(np.array([0.0, 1.0])).T)), 1.0, record)
        return {j: np.array(v) for j, v in record.items()}

    def tendon_points(self, t, X):
        d = t.offset(X, self.L)
        return np.array([p + R @ d[i] for i, (p, R) in enumerate(map(self.frame, X))])

    def _solve(self, steps, nodes, tol, warm=False, max_nodes=20000):
        s = np.linspace(0.0, 1.0, nodes)
        y = np.zeros((13 * self.nseg, s.size))
        q0 = rot_to_quat(self.R0)
        for k in range(self.nseg):
            X = self.cuts[k] + s * (self.cuts[k + 1] - self.cuts[k])
            y[13 * k:13 * k + 3] = self.p0[:, None] + self.R0[:, :1] * X
            y[13 * k + 3:13 * k + 7] = q0[:, None]
        sol = None
        if warm:
            s, y = self.solution.x, self.solution.y
        for lam in steps:
            if sol is not None and self.remesh:
                s = np.linspace(0.0, 1.0, self.remesh)
                y = sol.sol(s)
            sol = solve_bvp(lambda s, y: self.ode(s, y, lam), lambda a, b: self.bc(a, b, lam),
                            s, y, fun_jac=lambda s, y: self.ode_jacobian(s, y, lam), tol=tol,
                            max_nodes=max_nodes)
            if sol.status != 0:
                raise RuntimeError(f"reference BVP failed at load factor {lam}: {sol.message}")
            s, y = sol.x, sol.y
        self.solution = sol

    def frame(self, X):
        """Position and rotation matrix of the cross-section at X."""
        k = int(np.clip(np.searchsorted(self.cuts, X, side="right") - 1, 0, self.nseg - 1))
        a, b = self.cuts[k], self.cuts[k + 1]
        Y = self.solution.sol((X - a) / (b - a))[13 * k:13 * k + 7]
        return Y[:3], quat_to_rot(Y[3:7, None])[0]

    def tendon_length_changes(self):
        """Every tendon's path length through its disks (or along the rod, continuous) minus
        that on the straight rod."""
        out = {}
        for t in self.robot.tendons:
            if t.continuous:  # chords of a fine grid: O(h²), h = L / 8000
                X = np.linspace(0.0, self.L, 8001)
                slope = np.linalg.norm(t.offset(self.L, self.L) - t.offset(0.0, self.L)) / self.L
                out[t.name] = float(np.linalg.norm(np.diff(self.tendon_points(t, X), axis=0),
                                                   axis=1).sum() - self.L * np.hypot(1, slope))
                continue
            X = np.array(t.disks)
            d = t.offset(X, self.L)
            pts = np.array([p + R @ d[i] for i, (p, R) in enumerate(map(self.frame, X))])
            straight = d + X[:, None] * np.array([1.0, 0.0, 0.0])
            out[t.name] = float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()
                                - np.linalg.norm(np.diff(straight, axis=0), axis=1).sum())
        return out

    def position(self, X):
        k = int(np.clip(np.searchsorted(self.cuts, X, side="right") - 1, 0, self.nseg - 1))
        a, b = self.cuts[k], self.cuts[k + 1]
        return self.solution.sol((X - a) / (b - a))[13 * k:13 * k + 3]

    def markers(self):
        out = {}
        for m in self.robot.markers:
            k = int(np.clip(np.searchsorted(self.cuts, m.X, side="right") - 1, 0, self.nseg - 1))
            a, b = self.cuts[k], self.cuts[k + 1]
            Y = self.solution.sol((m.X - a) / (b - a))[13 * k:13 * k + 13]
            out[m.name] = Y[:3] + quat_to_rot(Y[3:7, None])[0] @ np.array(m.offset)
        return out
