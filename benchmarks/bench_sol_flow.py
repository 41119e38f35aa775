"""Sol's geodesic flows against each other and against a tight reference, side by side in one run
(not a test: times are the best of --repeat runs on a shared machine).

Flows, on the same rays (random start points in a box the size of the sol preset's domain, directions
uniform in the orthonormal frame there) at each length:
  - the tracer's C++ Taylor integrator, thurston_core.geodesic_flow("Sol", ...), at several accuracies;
  - the Python Taylor integrator Sol.geodesic (float64);
  - the Python elliptic closed form Sol.geodesic_elliptic (float64; rays within its guards of the
    degenerate cases go to the integrator, counted).
Reference: scipy's DOP853 at rtol = atol = 1e-13 on the full second-order geodesic equation (not the
reduced system the integrators share), one solve per ray and length. Its own floor is shown by the
Python Taylor integrator in long double (eps 1e-19): where the two agree to that floor, the long double
integrator is the tighter reference, and the float64 flows are also scored against it (and against
the float64 Taylor integrator, to compare the flows with each other).
A second, smaller set of rays sits on either side of the elliptic form's guards (|p_x p_y| near 0,
|p_x p_y| near 1/2), where the closed form loses digits.
Errors: Euclidean chart distance of the end point from the reference's (chart units).
Run: .venv/bin/python benchmarks/bench_sol_flow.py [--rays 200] [--lengths 0.1,1,5] [--repeat 3]
"""

import argparse
import math

import numpy as np
import thurston_core
from scipy.integrate import solve_ivp
from timing import best_of

from thurston_addon.geometries import sol
from thurston_addon.geometries.sol import Sol

ACCURACIES = (1e-6, 1e-9, 1e-12)
REFERENCE_TOLERANCE = 1e-13
LONG_DOUBLE = "Python Taylor, long double"


def frame_velocity(p, a):
    """Chart velocity at chart points p of the unit vectors a given in the orthonormal frame
    (e^{-z} d/dx, e^{z} d/dy, d/dz)."""
    return np.stack([np.exp(-p[:, 2]) * a[:, 0], np.exp(p[:, 2]) * a[:, 1], a[:, 2]], -1)


def random_rays(n, rng):
    p = rng.uniform(-0.5, 0.5, (n, 3)) * [1.0, 1.0, 2 * math.log((1 + math.sqrt(5)) / 2)]
    a = rng.normal(size=(n, 3))
    return p, a / np.linalg.norm(a, axis=1)[:, None]


def guard_rays(rng):
    """Rays on both sides of the elliptic form's guards: q = p_x p_y just inside and outside
    ELLIPTIC_MIN_PRODUCT, and s = sqrt(1 - 4 q^2) just inside and outside ELLIPTIC_MIN_MODULUS_GAP."""
    frames = []
    for q in (0.2, 0.5, 2.0, 10.0):  # in units of the guard
        c = rng.uniform(-0.9, 0.9, 5)
        r2 = 1 - c * c
        theta = 0.5 * np.arcsin(2 * q * sol.ELLIPTIC_MIN_PRODUCT / r2)
        frames.append(np.stack([np.sqrt(r2) * np.cos(theta), np.sqrt(r2) * np.sin(theta), c], -1))
    for s in (0.2, 0.5, 2.0, 10.0):
        r2 = math.sqrt(1 - (s * sol.ELLIPTIC_MIN_MODULUS_GAP) ** 2)  # r^4 = 1 - s^2, theta = pi/4
        c = math.sqrt(1 - r2) * rng.choice([-1.0, 1.0], 5)
        frames.append(np.stack([np.full(5, math.sqrt(r2 / 2)), np.full(5, math.sqrt(r2 / 2)), c], -1))
    a = np.vstack(frames)
    p = rng.uniform(-0.5, 0.5, (len(a), 3))
    return p, a


def guarded(a):
    """Which rays (unit vectors a in the orthonormal frame) the elliptic form hands to the integrator."""
    q = a[:, 0] * a[:, 1]
    s = np.sqrt(np.maximum(0.0, (1 - 2 * np.abs(q)) * (1 + 2 * np.abs(q))))
    return (np.abs(q) < sol.ELLIPTIC_MIN_PRODUCT) | (s < sol.ELLIPTIC_MIN_MODULUS_GAP)


def geodesic_rhs(_t, state):
    """x'' = -Gamma(x', x'): Gamma^x_xz = 1, Gamma^y_yz = -1, Gamma^z_xx = -e^{2z}, Gamma^z_yy = e^{-2z}."""
    _, _, z, vx, vy, vz = state
    return [vx, vy, vz, -2 * vx * vz, 2 * vy * vz, math.exp(2 * z) * vx * vx - math.exp(-2 * z) * vy * vy]


def check_rhs(g):
    """geodesic_rhs agrees with the geometry's Christoffel symbols (at one point)."""
    x, v = np.array([0.3, -0.2, 0.7]), np.array([0.1, -0.4, 0.5])
    expected = -np.einsum("kij,i,j->k", g.christoffel(x), v, v)
    assert np.allclose(geodesic_rhs(0, np.r_[x, v])[3:], expected, rtol=1e-14), "geodesic_rhs is not Sol's"


def reference(p, v, length):
    return np.array(
        [
            solve_ivp(
                geodesic_rhs,
                (0, length),
                np.r_[p[i], v[i]],
                method="DOP853",
                rtol=REFERENCE_TOLERANCE,
                atol=REFERENCE_TOLERANCE,
            ).y[:3, -1]
            for i in range(len(p))
        ]
    )


def flows(g, p, v, length, repeat):
    """name -> (seconds per geodesic, chart end points) of every flow on these rays."""
    n = len(p)
    t = np.full(n, float(length))
    P, V = g.to_model(p), g.tangent_to_model(p, v)
    out = {}
    for acc in ACCURACIES:
        sec, (x, _) = best_of(repeat, lambda: thurston_core.geodesic_flow("Sol", p, v, t, accuracy=acc))
        out[f"C++ Taylor, accuracy {acc:.0e}"] = (sec / n, x)
    for name, fn, args in (
        ("Python Taylor (Sol.geodesic)", g.geodesic, (P, V, t)),
        ("Python elliptic (Sol.geodesic_elliptic)", g.geodesic_elliptic, (P, V, t)),
        (LONG_DOUBLE, g.geodesic, tuple(np.asarray(a, np.longdouble) for a in (P, V, t))),
    ):
        sec, (X, _) = best_of(repeat, lambda: fn(*args))
        out[name] = (sec / n, np.asarray(g.to_chart(X), float))
    return out


def stats(e):
    return f"{np.median(e):.1e}", f"{np.percentile(e, 99):.1e}", f"{e.max():.1e}"


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--rays", type=int, default=200)
    ap.add_argument("--lengths", default="0.1,1,5")
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    lengths = [float(s) for s in args.lengths.split(",")]
    g = Sol()
    check_rhs(g)
    rng = np.random.default_rng(7)
    p, a = random_rays(args.rays, rng)
    v = frame_velocity(p, a)
    gp, ga = guard_rays(rng)
    gv = frame_velocity(gp, ga)
    print(
        f"{args.rays} random rays; the elliptic form handed {int(guarded(a).sum())} of them to its integrator "
        f"(guards |p_x p_y| < {sol.ELLIPTIC_MIN_PRODUCT:g}, sqrt(1 - 4 (p_x p_y)^2) < "
        f"{sol.ELLIPTIC_MIN_MODULUS_GAP:g}); {len(ga)} rays at the guards, {int(guarded(ga).sum())} of them "
        f"handed over. Errors in chart units against DOP853 (rtol = atol = {REFERENCE_TOLERANCE:g}); "
        f"'vs long double', 'vs Taylor': max distance from the Python Taylor integrator in long double, in "
        f"float64; 'at the guards': max distance from the long double one on the rays at the guards; C++ times: one "
        f"geodesic after another, Python's: vectorised over all rays.\n"
    )
    print(
        "| length | flow | median | 99th pct | max | max vs long double | max vs Taylor | max at the guards "
        "| µs/geodesic |"
    )
    print("|---|---|---|---|---|---|---|---|---|")
    summary = {}
    for length in lengths:
        sec, ref = best_of(1, lambda: reference(p, v, length))
        scale = np.abs(ref).max()
        random, at_guards = flows(g, p, v, length, args.repeat), flows(g, gp, gv, length, args.repeat)
        taylor, tight = random["Python Taylor (Sol.geodesic)"][1], random[LONG_DOUBLE][1]
        guards_tight = at_guards[LONG_DOUBLE][1]
        for name, (seconds, x) in random.items():
            e = np.linalg.norm(x - ref, axis=1)
            ld = np.linalg.norm(x - tight, axis=1).max()
            eg = np.linalg.norm(at_guards[name][1] - guards_tight, axis=1).max()
            vs = np.linalg.norm(x - taylor, axis=1).max()
            summary[length, name] = (ld, eg, seconds)
            label = name + " (the reference's floor)" if name == LONG_DOUBLE else name
            print(
                f"| {length:g} | {label} | {' | '.join(stats(e))} | {ld:.1e} | {vs:.1e} | {eg:.1e} | "
                f"{seconds * 1e6:.1f} |"
            )
        print(
            f"| {length:g} | DOP853 reference (largest chart coordinate {scale:.1f}) | | | | | | | "
            f"{sec / len(p) * 1e6:.0f} |"
        )
    print()
    longest = lengths[-1]
    cpp, taylor, ell = (
        summary[longest, k]
        for k in (
            f"C++ Taylor, accuracy {ACCURACIES[-1]:.0e}",
            "Python Taylor (Sol.geodesic)",
            "Python elliptic (Sol.geodesic_elliptic)",
        )
    )
    better = "the C++ Taylor integrator" if max(cpp[:2]) <= max(ell[:2]) else "the elliptic closed form"
    print(
        f"Conclusion (length {longest:g}, errors against the long double integrator): C++ Taylor at "
        f"{ACCURACIES[-1]:.0e}: max error {cpp[0]:.1e} "
        f"({cpp[1]:.1e} at the guards), {cpp[2] * 1e6:.1f} µs per geodesic; elliptic closed form: {ell[0]:.1e} "
        f"({ell[1]:.1e} at the guards), {ell[2] * 1e6:.1f} µs vectorised ({ell[2] / cpp[2]:.1f}x the C++ "
        f"time, {ell[2] / taylor[2]:.2f}x the Python Taylor's) -> the tracer should use {better}."
    )


if __name__ == "__main__":
    main()
