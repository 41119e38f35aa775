"""Graphs of Gaussians (the paper's Fig. 7.2): R^3 with the metric of the graph of a height function
f : R^3 -> R in R^4, pulled back to R^3:

    g = I + grad f grad f^T,   f(x) = s . x + sum_b h_b exp(-sum_i (x_i - c_bi)^2 / (2 w_bi^2)),

a sum of Gaussian bumps (centre c, height h, width w per axis) and an optional constant slope s.
With `period` (L_x, L_y, L_z) the bumps repeat on the lattice L_i Z (f is then periodic and the space
a flat 3-torus of that lattice with a non-homogeneous metric; the slope must be 0 there); without,
f lives on R^3 alone: a space file without generators is R^3 (open_torus, spaces/open_space.py).

Closed forms: with y = x - c and a_i = y_i / w_i^2, one bump G = h exp(-sum y_i a_i / 2) has
grad G = -G a and Hess G = G (a a^T - diag(1 / w^2)); g^-1 = I - grad f grad f^T / (1 + |grad f|^2)
and the Christoffel symbols are Gamma^k_ij = d_k f d_i d_j f / (1 + |grad f|^2), so the geodesic
equation is x'' = -grad f (x'^T Hess f x') / (1 + |grad f|^2). Periodic images: x is first reduced
into the cell |x_i - c_i| <= L_i / 2 about the bump (f is then periodic to rounding whatever is
summed), then the images n L with |n_i| <= m_i, m_i = ceil(IMAGE_CUTOFF w_i / L_i + 1/2), are
summed: every image left out lies more than IMAGE_CUTOFF widths away along some axis, so each is
below exp(-IMAGE_CUTOFF^2 / 2) = 2.6e-18 of h and together (a geometric tail) below 1e-17 |h|. The
lattice sum factorises by axes (_terms), so a bump costs 3 (2 m + 1) exponentials, not (2 m + 1)^3.

Isometries: none but the identity in general; the lattice translations in the periodic case (the
space file's generators must be such: checked on load, f(M x) = f(x) within 1e-12). Geodesics have
no closed form: `geodesic` integrates the equation above with scipy's DOP853 (the Python reference;
the core's kernel src/core/graph.hpp has its own adaptive integrator).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_ivp

from .affine import ISOMETRY_SAMPLE_POINTS, AffineGeometry, affine_matrix
from .shared import floats

IMAGE_CUTOFF = 9.0  # widths beyond which periodic images are left out (exp(-81 / 2) = 2.6e-18)
INTEGRATION_TOLERANCE = 1e-12  # DOP853's rtol and atol for the reference geodesics
PERIODIC_CHECK = 1e-12  # f(M x) - f(x) allowed for a generator M (relative to 1 + max |h|)


@dataclass(frozen=True)
class Bump:
    centre: tuple[float, float, float]
    height: float
    width: tuple[float, float, float]


class Graph(AffineGeometry):
    """The graph metric of f (see the module). Graph() is the flat one (f = 0), which the registry
    holds; a space file's [graph] table makes its own with `with_parameters`."""

    name = "graph"
    parameter_table = "graph"  # the space file's table that configures it (spaces.space.read_geometry)
    # The geodesics to a light have no closed form and shooting for them costs some 30 ms a copy
    # per shaded point: graph spaces render in the pseudo-colour shading modes only, without lights.
    point_lights = False
    open_spaces = True  # a space file without generators is R^3 (spaces/open_space.py)

    def __init__(self, bumps=(), slope=(0.0, 0.0, 0.0), period=None):
        self.bumps = tuple(bumps)
        self.slope = np.asarray(slope, float)
        self.period = None if period is None else np.asarray(period, float)
        if self.period is not None and np.any(self.slope != 0):
            raise ValueError("a periodic graph (period given) has no slope: a sloped f is not periodic")
        self._centres = np.array([b.centre for b in self.bumps], float).reshape(-1, 3)
        self._heights = np.array([b.height for b in self.bumps], float)
        self._widths = np.array([b.width for b in self.bumps], float).reshape(-1, 3)
        self.images = self._image_counts()

    # --- parameters ------------------------------------------------------------------------------
    def with_parameters(self, table, where="graph"):
        """The graph of a space file's [graph] table: bump = [{centre, height, width}, ...] (width a
        number or one per axis), slope = [sx, sy, sz], period = [Lx, Ly, Lz]. ValueError naming the
        key and what to change on bad input."""
        if not isinstance(table, dict):
            raise ValueError(f"{where}: expected a [graph] table (bump, slope, period), got {table!r}")
        unknown = set(table) - {"bump", "slope", "period"}
        if unknown:
            raise ValueError(f"{where}: unknown keys {sorted(unknown)} (known: bump, slope, period)")
        bumps = []
        for i, b in enumerate(table.get("bump", [])):
            w = f"{where}.bump[{i}]"
            if not isinstance(b, dict) or set(b) - {"centre", "height", "width"} or "height" not in b:
                raise ValueError(f"{w}: expected a [[graph.bump]] table with centre, height and width, got {b!r}")
            centre = _numbers(b.get("centre", [0, 0, 0]), 3, f"{w}.centre")
            height = _numbers([b["height"]], 1, f"{w}.height")[0]
            width = b.get("width", 1.0)
            width = _numbers([width] * 3 if isinstance(width, int | float) else width, 3, f"{w}.width")
            if not np.all(width > 0):
                raise ValueError(f"{w}.width must be positive numbers, got {width.tolist()}")
            bumps.append(Bump(tuple(centre), float(height), tuple(width)))
        slope = _numbers(table.get("slope", [0, 0, 0]), 3, f"{where}.slope")
        period = None
        if "period" in table:
            period = _numbers(table["period"], 3, f"{where}.period")
            if not np.all(period > 0):
                raise ValueError(f"{where}.period must be three positive lengths, got {period.tolist()}")
            if np.any(slope != 0):
                raise ValueError(f"{where}: slope must be 0 with a period (a sloped f is not periodic)")
        return Graph(bumps, slope, period)

    def open_torus(self, reach):
        """R^3's f as the period 2H of the lattice: H = max(reach, the farthest bump centre along an
        axis) + IMAGE_CUTOFF times the widest bump. Along each axis a point within reach and a
        bump's image n != 0 are then more than 2 IMAGE_CUTOFF widths apart, so the images add below
        1e-17 |h| there. ValueError where f is periodic already or has a slope."""
        if self.period is not None:
            raise ValueError("a [graph] period makes f periodic: give the lattice's generators, or no period for R^3")
        if np.any(self.slope != 0):
            raise ValueError("a slope is not supported in R^3 (a space file without generators): remove it")
        far = float(np.abs(self._centres).max()) if len(self.bumps) else 0.0
        widest = float(self._widths.max()) if len(self.bumps) else 0.0
        half = max(float(reach), far) + IMAGE_CUTOFF * widest
        return Graph(self.bumps, self.slope, [2 * half] * 3), half

    def _image_counts(self):
        """m (bumps, 3): the periodic images |n_i| <= m_i summed per bump (0: no period)."""
        if self.period is None:
            return np.zeros((len(self.bumps), 3), int)
        return np.ceil(IMAGE_CUTOFF * self._widths / self.period + 0.5).astype(int)

    @property
    def kernel_parameters(self) -> np.ndarray:
        """The bumps as the core's graph kernel reads them (src/core/graph.hpp): period (0: none),
        slope, then per bump centre, height, width, image counts."""
        head = [*(self.period if self.period is not None else np.zeros(3)), *self.slope]
        rows = [[*b.centre, b.height, *b.width, *m] for b, m in zip(self.bumps, self.images)]
        return np.array(head + [v for r in rows for v in r], float)

    def check_group(self, generators, where="graph"):
        """ValueError where f is not invariant under a generator within PERIODIC_CHECK (relative to
        1 + the largest |h|), at points about each bump and fixed sample points."""
        x = self.sample_points()
        scale = 1.0 + (np.abs(self._heights).max() if len(self.bumps) else 0.0)
        for i, M in enumerate(generators):
            gap = np.abs(self.height(self.transform_points(M, x)) - self.height(x)).max()
            if not gap <= PERIODIC_CHECK * scale:
                raise ValueError(
                    f"{where}: f is not invariant under generator {i} (it changes by {gap:.3g}): give a "
                    "[graph] period whose lattice holds the generators' translations"
                )

    def sample_points(self):
        """Points where f varies: the fixed sample points, each bump's centre and points a width
        away from it."""
        offsets = np.array([[0, 0, 0], [1, 0, 0], [0, -1, 0], [0, 0, 1], [0.7, 0.5, -0.6]], float)
        about = (self._centres[:, None, :] + offsets * self._widths[:, None, :]).reshape(-1, 3)
        return np.vstack([ISOMETRY_SAMPLE_POINTS, about])

    # --- f and its derivatives ------------------------------------------------------------------
    def _terms(self, x):
        """(values, gradients, Hessians) of f at chart points x (..., 3). A bump's lattice sum
        factorises by axes, sum_n prod_i phi_i(y_i - n_i L_i) = prod_i S_i with the 1-d sums
        S_i = sum_n phi_i(y_i - n L_i) (phi_i(u) = exp(-u^2 / (2 w_i^2))), so the derivatives
        are products of the S_i and their derivatives S_i', S_i''."""
        x = floats(x)
        value = x @ self.slope
        grad = np.broadcast_to(self.slope, x.shape).astype(x.dtype, copy=True)
        hess = np.zeros(x.shape + (3,))
        for b in range(len(self.bumps)):
            S, dS, ddS = self._axis_sums(x, b)
            value = value + self._heights[b] * S.prod(-1)
            for i in range(3):
                others = [S[..., j] for j in range(3) if j != i]
                grad[..., i] += self._heights[b] * dS[..., i] * others[0] * others[1]
                for j in range(3):
                    if i == j:
                        term = ddS[..., i] * others[0] * others[1]
                    else:
                        k = 3 - i - j
                        term = dS[..., i] * dS[..., j] * S[..., k]
                    hess[..., i, j] += self._heights[b] * term
        return value, grad, hess

    def _axis_sums(self, x, b):
        """S_i, S_i', S_i'' (each (..., 3)) of bump b at chart points x."""
        c, w, m = self._centres[b], self._widths[b], self.images[b]
        y = x - c
        S, dS, ddS = (np.zeros(x.shape) for _ in range(3))
        if self.period is not None:
            y = y - self.period * np.round(y / self.period)
        for n in range(-int(m.max()), int(m.max()) + 1):
            u = y - (0.0 if self.period is None else n * self.period)
            a = u / (w * w)
            phi = np.where(np.abs(n) <= m, np.exp(-0.5 * u * a), 0.0)
            S += phi
            dS -= a * phi
            ddS += (a * a - 1 / (w * w)) * phi
        return S, dS, ddS

    def height(self, x):
        """f at chart points x."""
        return self._terms(x)[0]

    def gradient(self, x):
        return self._terms(x)[1]

    def hessian(self, x):
        return self._terms(x)[2]

    @property
    def gradient_bound(self) -> float:
        """A bound of |grad f| over R^3: |s| plus, per bump, |h| sqrt(2 / e) / min w times the
        lattice sum of exp(-|y / w|^2 / 4) (sqrt(q) e^{-q/2} <= sqrt(2/e) e^{-q/4}), which is at most
        prod_i (1 + 2 sqrt(pi) w_i / L_i) (1 without a period)."""
        bound = float(np.linalg.norm(self.slope))
        for h, w in zip(self._heights, self._widths):
            images = 1.0 if self.period is None else float(np.prod(1 + 2 * math.sqrt(math.pi) * w / self.period))
            bound += abs(h) * math.sqrt(2 / math.e) / w.min() * images
        return bound

    # --- metric ---------------------------------------------------------------------------------
    def metric(self, x):
        grad = self.gradient(x)
        return np.eye(3) + grad[..., :, None] * grad[..., None, :]

    def christoffel(self, x):
        _, grad, hess = self._terms(x)
        return grad[..., :, None, None] * hess[..., None, :, :] / (1 + np.sum(grad * grad, -1))[..., None, None, None]

    def volume_density(self, x):
        """sqrt(det g) = sqrt(1 + |grad f|^2) (det(I + a a^T) = 1 + |a|^2)."""
        grad = self.gradient(x)
        return np.sqrt(1 + np.sum(grad * grad, -1))

    # --- geodesics --------------------------------------------------------------------------------
    def acceleration(self, x, u):
        """x'' = -grad f (u^T Hess f u) / (1 + |grad f|^2) at chart points x, chart velocities u."""
        _, grad, hess = self._terms(x)
        return -grad * (np.einsum("...i,...ij,...j->...", u, hess, u) / (1 + np.sum(grad * grad, -1)))[..., None]

    def chart_flow(self, x, u, t, tolerance=INTEGRATION_TOLERANCE):
        """Chart position and velocity at arclength t (...) from chart points x (..., 3) with unit
        chart velocities u: all rays in one DOP853 system, in the time s = tau / t in [0, 1]."""
        x, u, t = np.broadcast_arrays(floats(x), floats(u), floats(t)[..., None])
        shape = x.shape
        x, u, t = x.reshape(-1, 3), u.reshape(-1, 3), t.reshape(-1, 3)[:, 0]
        if not len(self.bumps) and not np.any(self.slope):
            return (x + t[:, None] * u).reshape(shape), u.reshape(shape)

        def rhs(_, y):
            p, v = y.reshape(2, -1, 3)
            return np.concatenate([(t[:, None] * v).ravel(), (t[:, None] * self.acceleration(p, v)).ravel()])

        sol = solve_ivp(
            rhs,
            (0.0, 1.0),
            np.concatenate([x.ravel(), u.ravel()]),
            method="DOP853",
            rtol=tolerance,
            atol=tolerance,
        )
        p, v = sol.y[:, -1].reshape(2, -1, 3)
        return p.reshape(shape), v.reshape(shape)

    def geodesic(self, P, V, t):
        P, V = floats(P), floats(V)
        x = self.to_chart(P)
        xt, ut = self.chart_flow(x, self.tangent_to_chart(P, V), t)
        return self.to_model(xt), np.concatenate([ut, np.zeros(ut.shape[:-1] + (1,))], axis=-1)

    def geodesic_path(self, P, V, length, tolerance=INTEGRATION_TOLERANCE):
        """One DOP853 solution of the ray to arclength `length`, its dense output (of the method's
        order) evaluated at any s in [0, length]: one integration where geodesic() would run one
        per call."""
        P, V = floats(P), floats(V)
        x, u = self.to_chart(P), self.tangent_to_chart(P, V)

        def rhs(_, y):
            return np.concatenate([y[3:], self.acceleration(y[:3], y[3:])])

        sol = solve_ivp(
            rhs,
            (0.0, float(length)),
            np.concatenate([x, u]),
            method="DOP853",
            rtol=tolerance,
            atol=tolerance,
            dense_output=True,
        )
        return lambda s: self.to_model(np.atleast_2d(sol.sol(np.atleast_1d(s))[:3].T))

    def exp_at(self, x, w):
        """exp_x(w) in the chart for chart vectors w at chart points x (w != 0)."""
        speed = np.sqrt(np.einsum("...i,...ij,...j->...", w, self.metric(x), w))
        return self.chart_flow(x, w / speed[..., None], speed)[0]

    def exp_jacobian_at(self, x, w, h=1e-5):
        """d exp_x at the chart vector w (..., 3, 3) by central differences."""
        x, w = np.broadcast_arrays(floats(x), floats(w))
        steps = h * np.eye(3)
        ends = [self.exp_at(x, w + e) for e in np.concatenate([steps, -steps])]
        ends = np.stack(ends)
        return np.moveaxis((ends[:3] - ends[3:]) / (2 * h), 0, -1)

    def connect(self, A, B, max_iterations=30):
        """(V, r, ok): unit tangent V at A and length r with geodesic(A, V, r) = B, by Newton on
        exp_A from the straight chart guess (the geodesic found, not always the shortest)."""
        a, b = np.broadcast_arrays(self.to_chart(A), self.to_chart(B))
        shape = a.shape[:-1]
        a, b = a.reshape(-1, 3), b.reshape(-1, 3)
        w = b - a
        for _ in range(max_iterations):
            moving = np.any(w != 0, axis=-1)
            end = a.copy()
            if moving.any():
                end[moving] = self.exp_at(a[moving], w[moving])
            residual = end - b
            if np.all(np.linalg.norm(residual, axis=-1) <= 1e-11 * (1 + np.linalg.norm(b, axis=-1))):
                break
            J = self.exp_jacobian_at(a, w)
            w = w - np.linalg.solve(J, residual[..., None])[..., 0]
        speed = np.sqrt(np.einsum("ni,nij,nj->n", w, self.metric(a), w))
        ok = np.linalg.norm(residual, axis=-1) <= 1e-9 * (1 + np.linalg.norm(b, axis=-1))
        direction = np.where((speed > 0)[:, None], w / np.where(speed > 0, speed, 1)[:, None], np.eye(3)[0])
        V = self.normalize_tangent(self.to_model(a), self.tangent_to_model(a, direction))
        V, r = np.where(ok[:, None], V, np.nan), np.where(ok, speed, np.nan)
        return V.reshape(shape + (4,)), r.reshape(shape), ok.reshape(shape)

    def falloff_along(self, P, V, r):
        """1 / (r^2 |det d exp_P(r V)|) in orthonormal frames: the chart Jacobian's determinant times
        sqrt(det g) at the end over sqrt(det g) at P."""
        P, V, r = floats(P), floats(V), floats(r)
        x = self.to_chart(P)
        w = self.tangent_to_chart(P, V) * r[..., None]
        end = self.chart_flow(x, self.tangent_to_chart(P, V), r)[0]
        J = np.abs(np.linalg.det(self.exp_jacobian_at(x, w)))
        return self.volume_density(x) / (r * r * J * self.volume_density(end))

    # --- distance bounds ---------------------------------------------------------------------------
    def distance_bound(self, A, B):
        """The length of the chart segment from A to B is at most |B - A| sqrt(1 + G^2), G the
        gradient bound."""
        d = np.linalg.norm(self.to_chart(B) - self.to_chart(A), axis=-1)
        return d * math.sqrt(1 + self.gradient_bound**2)

    def farthest_distance(self, X, domain):
        """distance_bound to the farthest vertex (the chart distance to a convex domain is largest at
        a vertex)."""
        return float(np.max(self.distance_bound(X, self.to_model(domain.vertices))))

    def domain_distance(self, X, domain):
        """The chart distance to the box about the domain: g >= I, so no curve is shorter than its
        chart length."""
        x = self.to_chart(X)
        lo, hi = domain.vertices.min(axis=0), domain.vertices.max(axis=0)
        return np.linalg.norm(np.maximum(np.maximum(lo - x, x - hi), 0.0), axis=-1)

    # --- isometries -------------------------------------------------------------------------------
    def is_isometry(self, M, tol=1e-9):
        """M is an affine map that pulls g back onto itself at the sample points (those of
        AffineGeometry and about every bump)."""
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)) or not np.allclose(M[3], [0, 0, 0, 1], atol=tol):
            return False
        A, x = M[:3, :3], self.sample_points()
        pulled = np.einsum("ki,nkl,lj->nij", A, self.metric(x @ A.T + M[:3, 3]), A)
        return bool(np.all(np.abs(pulled - self.metric(x)) <= tol * (1 + np.abs(self.metric(x)))))

    def reorthonormalize(self, M):
        """The translation rebuilt where M is one (the periodic case's lattice), else M."""
        M = np.asarray(M, float)
        T = affine_matrix(np.eye(3), M[:3, 3])
        return T if np.abs(M - T).max() <= 1e-6 * max(1.0, np.abs(M).max()) else M


def _numbers(value, n, where):
    try:
        a = np.array(value, float).reshape(n)
    except (TypeError, ValueError):
        raise ValueError(f"{where} must be {n} number{'s' if n > 1 else ''}, got {value!r}") from None
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{where} must be finite, got {value!r}")
    return a
