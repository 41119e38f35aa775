"""What the three isotropic geometries share: a projective chart in which geodesics are straight.

Points are homogeneous 4-vectors X ("model" coordinates) with chart point x = X[:3] / X[3]:
E3 uses X = (x, 1); S3 the unit sphere of R^4 (gnomonic chart); H3 the upper sheet of the
hyperboloid <X, X> = -1 of R^{3,1} (Klein chart). Isometries are 4x4 matrices acting linearly on X.
A plane of the chart is a covector c with c . X = 0; the same covector works in every geometry.
Everything is float64 numpy and broadcasts over leading axes.
"""

from __future__ import annotations

import math

import numpy as np

from .shared import SharedGeometry, floats

ORIGIN = np.array([0.0, 0.0, 0.0, 1.0])


def _dot(a, b):
    return np.einsum("...i,...i->...", a, b)


# --- H3's isometries as spinors: SO+(3,1) = SL(2, C) / ±1 ----------------------------------------
# A model point X = (X1, X2, X3, X0) is the Hermitian matrix H(X) = [[X0 + X3, X1 - i X2],
# [X1 + i X2, X0 - X3]] (det H = -<X, X>), and A in SL(2, C) acts by H -> A H A^†. Everything
# broadcasts over leading axes.
_MIRROR = np.diag([1.0, 1.0, -1.0, 1.0])


def _hermitian(X):
    """H(X) (..., 2, 2) of vectors X (..., 4) (complexified: linear in X)."""
    X1, X2, X3, X0 = np.moveaxis(X, -1, 0)
    return np.stack([np.stack([X0 + X3, X1 - 1j * X2], -1), np.stack([X1 + 1j * X2, X0 - X3], -1)], -2)


# Both directions are linear, so each is one complex matrix (16, 16). _IMAGES: M's entries -> the
# images A E_kl A^† [k, l, i, j] of the matrix units (E_kl = H(_UNITS[k, l])), whose entries are
# A_ik conj(A_jl). _LORENTZ: those products [i, k, j, l] -> M [a, e], whose column e is the vector
# of A H(e) A^†, its coordinate a the real part of sum_ij _READ[a, i, j] H_ij.
_UNITS = np.array([[[0, 0, 0.5, 0.5], [0.5, 0.5j, 0, 0]], [[0.5, -0.5j, 0, 0], [0, 0, -0.5, 0.5]]])
_IMAGES = _hermitian(np.einsum("mab,klb->mkla", np.eye(16).reshape(16, 4, 4), _UNITS)).reshape(16, 16)
_READ = np.array([[[0, 0], [1, 0]], [[0, 0], [-1j, 0]], [[0.5, 0], [0, -0.5]], [[0.5, 0], [0, 0.5]]])
_LORENTZ = np.einsum("aij,ekl->ikjlae", _READ, _hermitian(np.eye(4))).reshape(16, 16)
_J, _L = np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1])  # the entries (j, l) of A, in turn
_I2, _K2 = np.array([[0, 0], [1, 1]]), np.array([[0, 1], [0, 1]])  # [i, k] of a 2 x 2 matrix


def spinor_of_lorentz(M) -> np.ndarray:
    """A in SL(2, C) (up to sign) whose action is the orientation- and time-preserving Lorentz
    matrix M: its entries divided from the products A_ik conj(A_jl) that M's images of the matrix
    units hold, by the largest |A_jl| (so each entry keeps M's relative rounding); then brought to
    determinant 1 by the least change of its entries (one Newton step: det B = B00 B11 - B01 B10
    cancels terms of size |M| down to 1, so B / sqrt(det B) would scale every entry by the
    rounding of |M|, eps |M| relative; the step moves each entry by eps of its size)."""
    M = np.asarray(M, float)
    images = (M.reshape(-1, 16) @ _IMAGES).reshape(-1, 2, 2, 2, 2)  # [n, k, l, i, j]
    squares = images[:, _L, _L, _J, _J].real  # |A_jl|^2
    n, c = np.arange(len(images)), np.argmax(squares, axis=1)
    B = images[n[:, None, None], _K2, _L[c][:, None, None], _I2, _J[c][:, None, None]]  # A up to a phase
    B = B / np.sqrt(squares[n, c])[:, None, None]
    det = B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]
    B = B / np.sqrt(det / np.abs(det))[:, None, None]  # the phase that makes det B real (about 1)
    det = B[:, 0, 0] * B[:, 1, 1] - B[:, 0, 1] * B[:, 1, 0]
    adjugate_h = np.conj(np.stack([B[:, 1, 1], -B[:, 1, 0], -B[:, 0, 1], B[:, 0, 0]], -1)).reshape(-1, 2, 2)
    A = B + ((1.0 - det) / np.sum(np.abs(B) ** 2, axis=(1, 2)))[:, None, None] * adjugate_h
    return A.reshape(M.shape[:-2] + (2, 2))


def lorentz_of_spinor(A) -> np.ndarray:
    """The Lorentz matrices (..., 4, 4) of the actions H -> A H A^†."""
    A = np.asarray(A, complex)
    flat = A.reshape(-1, 2, 2)
    products = np.einsum("nik,njl->nikjl", flat, np.conj(flat)).reshape(-1, 16)
    return (products @ _LORENTZ).real.reshape(A.shape[:-2] + (4, 4))


def repaired_lorentz(M) -> np.ndarray:
    """Lorentz matrices (..., 4, 4) repaired through their spinors; for an orientation-reversing
    M (whose spinor's matrix then lies far from it), that of M P times P, P the mirror in x3 = 0.
    (Which one M is cannot be told from det M: its terms reach |M|^4, so its rounding swamps the
    ±1 past |M| = 10^4.)"""
    M = np.asarray(M, float)
    flat = M.reshape(-1, 4, 4)
    with np.errstate(invalid="ignore", divide="ignore"):  # (the wrong orientation's spinor may be NaN)
        repaired = lorentz_of_spinor(spinor_of_lorentz(flat))
        off = np.nan_to_num(np.abs(repaired - flat).max(axis=(-2, -1)), nan=np.inf)
        far = ~(off <= 1e-6 * np.abs(flat).max(axis=(-2, -1)))
        if far.any():
            mirrored = lorentz_of_spinor(spinor_of_lorentz(flat[far] @ _MIRROR)) @ _MIRROR
            nearer = np.nan_to_num(np.abs(mirrored - flat[far]).max(axis=(-2, -1)), nan=np.inf) < off[far]
            repaired[np.flatnonzero(far)[nearer]] = mirrored[nearer]
    return repaired.reshape(M.shape)


class ProjectiveGeometry(SharedGeometry):
    """Base class: subclasses set `name`, `curvature` and the form `form` (diagonal of the
    ambient bilinear form restricted as the metric sees it)."""

    name: str
    curvature: int
    form: np.ndarray  # diagonal of the ambient form on R^4 (the last entry is unused in E3)
    projective = True  # geodesics and bisectors are straight in the chart: Dirichlet domains
    copy_rings = 3  # rings of neighbouring domains searched for the parts of large objects
    reference_depth = math.inf  # how deep `geodesic` in the universal cover is a reference

    @property
    def diameter(self) -> float:
        """The largest distance between two points (S3: pi; E3, H3: unbounded)."""
        return math.pi if self.curvature > 0 else math.inf

    @property
    def antipode_distance(self) -> float:
        """S3: every geodesic from X reaches -X at pi; E3, H3 have no antipodes (-X is no point of H3's sheet)."""
        return math.pi if self.curvature > 0 else math.inf

    def cos_sin(self, t):
        """The generalised cosine and sine of the geodesic flow (E3: 1 and t)."""
        raise NotImplementedError

    def distance(self, A, B):
        """Geodesic distance between model points."""
        raise NotImplementedError

    def falloff(self, r):
        """Point-light falloff at geodesic distance r: 1 / (area of the sphere of radius r / 4 pi)."""
        raise NotImplementedError

    # --- the ambient form and the metric ---------------------------------------------------
    def inner(self, a, b):
        """Ambient bilinear form; on tangent vectors of the model it is the Riemannian metric."""
        return _dot(a * self.form, b)

    def metric(self, x):
        """Riemannian metric of the chart at chart points x: (..., 3, 3)."""
        x = np.asarray(x, float)
        k = self.curvature
        d = 1.0 + k * _dot(x, x)
        eye = np.broadcast_to(np.eye(3), x.shape[:-1] + (3, 3))
        return eye / d[..., None, None] - k * np.einsum("...i,...j->...ij", x, x) / (d * d)[..., None, None]

    def volume_density(self, x):
        """sqrt(det g) of the chart metric."""
        x = np.asarray(x, float)
        return (1.0 + self.curvature * _dot(x, x)) ** -2

    def christoffel(self, x):
        """Christoffel symbols of the chart, [..., k, i, j] = Gamma^k_ij: in a projective chart
        geodesics are straight, and Gamma^k_ij = -k (x_i delta_jk + x_j delta_ik) / (1 + k |x|^2)."""
        x = np.asarray(x, float)
        k = self.curvature
        psi = -k * x / (1.0 + k * _dot(x, x))[..., None]
        eye = np.eye(3)
        return np.einsum("...i,kj->...kij", psi, eye) + np.einsum("...j,ki->...kij", psi, eye)

    def dot(self, X, A, B):
        """The metric at the model point X on model tangent vectors (the ambient form)."""
        return self.inner(A, B)

    # --- charts ---------------------------------------------------------------------------
    def to_chart(self, X):
        X = np.asarray(X, float)
        return X[..., :3] / X[..., 3:4]

    def to_model(self, x):
        x = np.asarray(x, float)
        Y = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)
        return self.normalize_point(Y)

    def in_chart(self, x):
        """Whether chart points are points of the geometry (H3: inside the unit ball)."""
        x = np.asarray(x, float)
        ok = np.all(np.isfinite(x), axis=-1)
        if self.curvature < 0:
            ok &= _dot(x, x) < 1.0
        return ok

    def tangent_to_model(self, x, u):
        """Push a chart tangent vector u at chart point x to the model (differential of to_model)."""
        x = np.asarray(x, float)
        u = np.asarray(u, float)
        Y = np.concatenate([x, np.ones(x.shape[:-1] + (1,))], axis=-1)
        dY = np.concatenate([u, np.zeros(u.shape[:-1] + (1,))], axis=-1)
        if self.curvature == 0:
            return dY
        scale = np.sqrt(self.curvature * self.inner(Y, Y))[..., None]
        X = Y / scale
        return (dY - self.curvature * self.inner(X, dY)[..., None] * X) / scale

    def tangent_to_chart(self, X, V):
        """Chart velocity of a model tangent vector V at X (differential of to_chart)."""
        X = np.asarray(X, float)
        V = np.asarray(V, float)
        return (V[..., :3] - X[..., :3] * (V[..., 3:4] / X[..., 3:4])) / X[..., 3:4]

    # --- staying on the model ----------------------------------------------------------------
    def normalize_point(self, X):
        X = floats(X)
        if self.curvature == 0:
            return X / X[..., 3:4]
        return X / np.sqrt(self.curvature * self.inner(X, X))[..., None]

    def normalize_tangent(self, X, V):
        """Project V onto the tangent space at X and scale it to unit length in the metric."""
        V = floats(V)
        if self.curvature == 0:
            V = V.copy()
            V[..., 3] = 0.0
        else:
            V = V - self.curvature * self.inner(X, V)[..., None] * X
        return V / np.sqrt(self.inner(V, V))[..., None]

    # --- geodesics -------------------------------------------------------------------------
    def geodesic(self, P, V, t):
        """Position and unit velocity at arclength t along the geodesic from P with unit tangent V
        (extended precision is kept where the input has it)."""
        P, V, t = floats(P), floats(V), floats(t)[..., None]
        c, s = self.cos_sin(t)
        return c * P + s * V, -self.curvature * s * P + c * V

    def chord_distance(self, A, B):
        """The distance of nearby model points to first order, from the model chord: 2 sin(r/2),
        2 sinh(r/2) or r (S3, H3, E3). Keeps extended precision."""
        d = floats(B) - floats(A)
        square = np.sum(d[..., :3] ** 2, axis=-1)
        if self.curvature != 0:
            square = np.maximum(square + self.curvature * d[..., 3] ** 2, 0)
        return np.sqrt(square)

    def connect(self, A, B):
        """(V, r, ok): the unit tangent at A and length of the shortest geodesic to B, in closed form."""
        r = self.distance(A, B)
        return self.direction_to(A, B), r, np.ones(np.shape(r), bool)

    def falloff_along(self, P, V, r):
        """The falloff of a point light at P seen at distance r along (P, V): isotropic here."""
        return self.falloff(r)

    def direction_to(self, A, B):
        """Unit tangent at A of the geodesic from A to B (the shortest one in S3)."""
        A, B = np.asarray(A, float), np.asarray(B, float)
        if self.curvature == 0:
            return self.normalize_tangent(A, B / B[..., 3:4] - A / A[..., 3:4])
        return self.normalize_tangent(A, B)

    # --- isometries ------------------------------------------------------------------------
    def is_isometry(self, M, tol=1e-9):
        M = np.asarray(M, float)
        if M.shape != (4, 4) or not np.all(np.isfinite(M)):
            return False
        if self.curvature == 0:
            R = M[:3, :3]
            return bool(np.allclose(M[3], [0, 0, 0, 1], atol=tol) and np.allclose(R.T @ R, np.eye(3), atol=tol))
        J = np.diag(self.form)
        ok = np.allclose(M.T @ J @ M, J, atol=tol * max(1.0, np.abs(M).max() ** 2))
        # H3: the isometries are the maps that keep the upper sheet of the hyperboloid
        return bool(ok and (self.curvature > 0 or M[3, 3] > 0))

    def rotation(self, axis, angle):
        """Rotation by `angle` (right-handed) about the geodesic through the origin along `axis`."""
        a = np.asarray(axis, float)
        a = a / np.linalg.norm(a)
        K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        M = np.eye(4)
        M[:3, :3] = np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * (K @ K)
        return M

    def translation(self, direction, distance):
        """Translation by `distance` along the geodesic through the origin in chart direction `direction`."""
        n = np.asarray(direction, float)
        n = n / np.linalg.norm(n)
        M = np.eye(4)
        c, s = self.cos_sin(distance)
        nn = np.outer(n, n)
        M[:3, :3] = np.eye(3) + (c - 1.0) * nn
        M[:3, 3] = s * n
        M[3, :3] = -self.curvature * s * n
        M[3, 3] = c
        return M

    def translation_to(self, Q):
        """The translation along the geodesic from the origin that takes it to the model point Q,
        built from Q's coordinates directly (cos/cosh d = Q[3], sin/sinh d n = Q[:3])."""
        M = np.eye(4)
        r = np.linalg.norm(Q[:3])
        n = Q[:3] / r if r > 0 else np.zeros(3)
        M[:3, :3] += (Q[3] - 1.0) * np.outer(n, n)
        M[:3, 3] = Q[:3]
        M[3, :3] = -self.curvature * Q[:3]
        M[3, 3] = Q[3]
        return M

    def element_key(self, M):
        """Identifies a group element: the image of the origin does (the action is free), plus the
        linear part in E3, where a lattice translation and a screw can move the origin alike."""
        key = tuple(np.round(M[:, 3], 7))
        return key + tuple(np.round(M[:3, :3].ravel(), 5)) if self.curvature == 0 else key

    def reorthonormalize(self, M):
        """Nearest isometry to an almost-isometry M (removes accumulated rounding). E3: the linear
        part repaired by SVD. H3: through M's spinor in SL(2, C), which keeps every entry to its own
        relative rounding (a repair of M itself, Gram-Schmidt or T^-1 M, computes a rotation from
        differences of entries of size |M|^2, so it errs by eps |M|^2 relative: 1e-10 at |M| = 1000,
        and past |M| = 10^5 its SVD fails). S3: M split into the translation taking the origin to
        M's image of it, computed exactly, and a rotation about the origin, repaired by SVD."""
        M = np.array(M, float)
        if self.curvature == 0:
            U, _, Vt = np.linalg.svd(M[:3, :3])
            M[:3, :3] = U @ Vt
            M[3] = [0, 0, 0, 1]
            return M
        if self.curvature < 0:
            return repaired_lorentz(M)
        T = self.translation_to(self.normalize_point(M[:, 3]))
        J = np.diag(self.form)
        R = (J @ T.T @ J) @ M  # T^-1 M, nearly a rotation about the origin
        U, _, Vt = np.linalg.svd(R[:3, :3])
        R = np.eye(4)
        R[:3, :3] = U @ Vt
        return T @ R

    def transform_points(self, M, x):
        """Apply an isometry to chart points."""
        X = self.to_model(x)
        return self.to_chart(X @ np.asarray(M).T)

    # --- planes (covectors) ---------------------------------------------------------------
    def bisector(self, Q):
        """Covector c of the plane of points equidistant from the origin and Q, with
        c . X <= 0 on the origin's side."""
        Q = self.normalize_point(np.asarray(Q, float))
        if self.curvature == 0:
            q = Q[:3]
            return np.append(2.0 * q, -q @ q)
        # S3: X.O >= X.Q; H3: -<X,O> <= -<X,Q>; both linear in X
        return (Q - ORIGIN) * self.form

    def covector_dual_form(self):
        """Diagonal form on covectors whose restriction measures dihedral angles."""
        return np.array([1.0, 1.0, 1.0, float(self.curvature)])

    def dihedral_angle(self, c1, c2):
        """Interior dihedral angle between the half-spaces c1 . X <= 0 and c2 . X <= 0."""
        f = self.covector_dual_form()
        g = lambda a, b: np.sum(a * f * b, axis=-1)
        cos = -g(c1, c2) / np.sqrt(g(c1, c1) * g(c2, c2))
        return np.arccos(np.clip(cos, -1.0, 1.0))

    def plane_distances(self, X, C):
        """Signed geodesic distances from model points X to the planes of the covectors C (rows;
        positive on the side c . X > 0)."""
        X, C = np.asarray(X, float), np.asarray(C, float)
        norm = np.sqrt(np.sum(C * C * self.covector_dual_form(), axis=1))
        s = (X @ C.T) / norm
        if self.curvature == 0:
            return s / X[..., 3:4]
        return np.arcsin(np.clip(s, -1, 1)) if self.curvature > 0 else np.arcsinh(s)

    def cone_radial_integral(self, R):
        """Integral of the volume density times r^2 along a chart ray from 0 to R (cone volumes)."""
        R = np.asarray(R, float)
        k = self.curvature
        if k == 0:
            return R**3 / 3
        if k > 0:
            return 0.5 * (np.arctan(R) - R / (1 + R * R))
        return 0.5 * (R / (1 - R * R) - np.arctanh(R))

    def domain_distance(self, X, domain):
        """Distances from model points X to a convex domain, bounded below by the largest signed
        distance to its face planes (0 inside)."""
        return np.maximum(np.max(self.plane_distances(X, domain.covectors()), axis=-1), 0.0)

    def plane_distance(self, c):
        """Geodesic distance from the origin to the plane c . X = 0."""
        c = np.asarray(c, float)
        n = np.linalg.norm(c[..., :3], axis=-1)
        r = np.abs(c[..., 3]) / n
        if self.curvature == 0:
            return r
        return np.arctan(r) if self.curvature > 0 else np.arctanh(r)
