"""Direct light along every geodesic (E3, S3, H3, H2xR, S2xR; Nil, Sol, SL2 in test_light_curved.py) against
closed forms: the sum over the copies of a point light (in S3 over both arcs to each, in S2xR over every arc round the sphere) of
cos * power * falloff, where nothing shadows (the shaded object is emissive, so it casts no
shadow on point lights' light, and there is nothing else), every path shadowed where the light is shut in, and the
render's light statistics."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import trimesh
from support.lit_ball import GLOW, RHO, ball_scene, shade_one
from support.presets import simplest_per_geometry

from thurston_addon import render, spaces
from thurston_addon.scenes import PointLight, Scene, SceneObject, default_scene


@pytest.mark.parametrize("fog", [math.inf, 0.5])
def test_torus_sums_every_lattice_copy_within_the_reach(fog):
    """E3: the irradiance at a point of the ball is sum_k max(0, cos theta_k) p / r_k^2 over the
    lattice copies L + k of the light with r_k <= reach (every one visible), to float precision;
    with fog each term falls by exp(-r_k / fog). The trace counts those geodesics that arrive at
    the point's front and sums p / r_k^2 exp(-r_k / fog) over them (the energy the stats set the
    part beyond against)."""
    space = spaces.load("torus")
    light, power, reach = np.array([-0.2, 0.1, 0.3]), 0.7, 2.5
    colour, H, N, out = shade_one(
        space, ball_scene([0.1, 0.2, -0.15], light, power), [0.1, -0.2, -0.15], [0.1, 0.2, -0.15], reach, fog
    )
    x = H[:3] / H[3]
    total, energy, facing = 0.0, 0.0, 0
    for k in itertools.product(range(-4, 5), repeat=3):
        v = light + np.array(k) - x
        r = np.linalg.norm(v)
        assert abs(r - reach) > 1e-6  # no copy on the boundary of the reach
        if r <= reach and N[:3] @ v > 0:
            energy += power / r**2 * math.exp(-r / fog)
            total += (N[:3] @ v / r) * power / r**2 * math.exp(-r / fog)
            facing += 1
    assert facing > 20  # many copies, not just the nearest
    np.testing.assert_allclose(colour, GLOW + RHO * total, rtol=2e-5)
    assert out["light_paths"] == facing
    assert float(out["light_energy"]) == pytest.approx(energy, rel=1e-6)  # the radiance is float32


def test_poincare_sums_120_copies_and_both_arcs():
    """S3, the Poincare sphere: sum over the 120 copies g L and the two arcs to each (the short one
    of length d, the long one of length 2 pi - d leaving the other way, falloff 1/sin^2 on both)
    of max(0, cos) p / sin^2: that is |N . u_k| p / sin^2 d_k for the unit direction u_k of the
    short arc. Computed from the group's matrices in R^4, against the traced value to 1e-4."""
    space = spaces.load("poincare")
    g = space.geometry
    group = space.elements_within(math.pi + 1e-6)
    assert len(group) == 120
    light, power = np.array([0.08, -0.05, 0.12]), 0.3
    colour, H, N, out = shade_one(
        space, ball_scene([0.0, 0.15, 0.0], light, power), [0.0, -0.1, 0.0], [0.0, 0.15, 0.0], None
    )
    L = g.normalize_point(g.to_model(light[None]))[0]
    total = 0.0
    for M in group:
        Y = M @ L
        d = math.acos(np.clip(H @ Y, -1, 1))
        u = Y - (H @ Y) * H
        u /= np.linalg.norm(u)
        total += abs(N @ u) * power / math.sin(d) ** 2
    np.testing.assert_allclose(colour, GLOW + RHO * total, rtol=1e-4)
    assert out["light_paths"] == 120  # every copy, by the one of its two arcs that meets the front


def test_opaque_points_in_the_poincare_sphere_see_no_long_arcs():
    """-1 is in the binary icosahedral group, so a geodesic returns to its start after length pi: a
    long arc from an opaque surface passes through that surface again. Traced (the geodesic_loop
    shortcut off) and with the shortcut, the image is the same."""
    space = spaces.load("poincare")
    scene = default_scene(space)
    assert render.geodesic_loop(space) == math.pi
    # every geodesic walked (a visibility map answers the long arcs only to its texels)
    settings = render.Settings(width=24, height=16, quality="draft", threads=1, light_map=0)
    shortcut = render.render(space, scene, settings).passes["color"]
    data = render.compile_scene(space, scene, 2 * math.pi)
    import thurston_core

    traced = render.render(
        space,
        scene,
        settings,
        tracer=thurston_core.Tracer(render.core_scene({**data, "geodesic_loop": math.inf}), threads=1),
    ).passes["color"]
    np.testing.assert_allclose(shortcut, traced, rtol=1e-4, atol=1e-6)


def test_light_stats_and_energy_estimate():
    """The stats count the copies and the geodesics, and estimate the energy beyond the reach:
    4 pi p (D - R) / vol against what was summed; S3 with every copy and both arcs: 0."""
    torus = spaces.load("torus")
    scene = default_scene(torus)
    near = render.render(torus, scene, render.Settings(width=32, height=18, quality="draft", light_reach=1.0))
    far = render.render(torus, scene, render.Settings(width=32, height=18, quality="draft", light_reach=2.0))
    for r in (near, far):
        assert r.stats["light_copies"] > 1 and r.stats["light_paths_per_point"] > 1
        assert "copies within reach" in r.summary()
    assert far.stats["light_copies"] > near.stats["light_copies"]
    # beyond R = 1 up to D = 30 there is far more than the summed part: (D - R) / R ~ 29, roughly
    assert (
        5 < near.stats["light_energy_left_out"]
        and far.stats["light_energy_left_out"] < near.stats["light_energy_left_out"]
    )
    poincare = spaces.load("poincare")
    r = render.render(poincare, default_scene(poincare), render.Settings(width=16, height=9, quality="draft"))
    assert r.stats["light_copies"] == 120 and r.stats["light_energy_left_out"] == 0.0
    sw = spaces.load("seifert_weber")
    r = render.render(sw, default_scene(sw), render.Settings(width=16, height=9, quality="draft"))
    assert math.isfinite(r.stats["light_reach"]) and 0 < r.stats["light_energy_left_out"] < math.inf
    # every copy within the reach, along every geodesic, in a space of each geometry whose geodesics bend
    for sid in simplest_per_geometry(lambda space: not space.geometry.projective):
        space = spaces.load(sid)
        r = render.render(space, default_scene(space), render.Settings(width=16, height=9, quality="draft"))
        assert r.stats["light_reach"] == pytest.approx(render.default_light_reach(space))
        assert r.stats["light_copies"] > 1 and r.stats["light_paths_per_point"] > 1
        assert 0 < r.stats["light_energy_left_out"] < math.inf and r.stats["light_failures"] == 0
        assert "copies within reach" in r.summary()


@pytest.mark.parametrize("reach", [-1.0, float("nan")])
def test_bad_light_reach_is_one_clear_error(reach):
    with pytest.raises(render.RenderError, match="light reach"):
        render.render(spaces.load("torus"), Scene(), render.Settings(width=4, height=4, light_reach=reach))


# --- the floor under the lamp (issue 9) against Cycles in the tiled universal cover -------------------
CYCLES_CELLS, CYCLES_REACH = 7, 3.5


def test_floor_under_the_lamp_matches_cycles_in_the_tiled_cover(tmp_path, registered_addon):
    """The floor is lit, and pixel by pixel as Cycles renders the scene tiled 7x7x7 in the universal
    cover (direct light only, all 343 lamps lighting everything): the points of the central cell
    (no face crossed), lit by every copy within reach 3.5 (Cycles' tiling holds the corridor's
    lamps three cells each way; the ones one cell further, at reach 3.5 to 4, send under 1%). A
    missing copy fails it: the reach that keeps only the lamp's own copy. Sampled light (8 walks per
    point, 32 samples) matches too."""
    from support import blender_helpers as bh

    sc = bh.floor_under_lamp()
    sc.view_layers[0].thurston.use_pass_crossings = True
    L = "ViewLayer."
    sc.thurston.light_reach = CYCLES_REACH
    ch = bh.f12(sc, tmp_path / "thurston.exr")
    thurston = bh.rgb(ch, L + "Combined.")
    central = bh.interior(next(v for k, v in ch.items() if "Crossings" in k) < 0.5)
    # sampled light: 8 of the copies' geodesics walked per point (the walls shadow most), 32 samples
    sc.thurston.light_paths, sc.thurston.samples = 8, 32
    sampled = bh.rgb(bh.f12(sc, tmp_path / "sampled.exr"), L + "Combined.")
    sc.thurston.light_paths, sc.thurston.samples = -1, 0
    sc.thurston.light_reach = 0.9  # the lamp's own copy only (the ones a cell away are farther)
    own_only = bh.rgb(bh.f12(sc, tmp_path / "own.exr"), L + "Combined.")
    bh.tile_torus_for_cycles(sc, CYCLES_CELLS)
    cycles = bh.rgb(bh.cycles_render(sc, tmp_path / "cycles.exr", samples=1024), L + "Combined.")
    assert central.sum() > 300
    assert thurston[central].mean() > 0.05  # lit

    def error(image):  # the per-pixel differences from Cycles relative to its brightness
        return float(np.abs(image[central] - cycles[central]).sum() / cycles[central].sum())

    report = {"all copies": error(thurston), "sampled": error(sampled), "own copy only": error(own_only)}
    print("mean relative per-pixel difference from Cycles:", report)
    np.testing.assert_allclose(thurston[central].mean(axis=0), cycles[central].mean(axis=0), rtol=0.02)
    assert report["all copies"] < 0.05, report  # Cycles' noise at 1024 samples: about 0.03
    np.testing.assert_allclose(sampled[central].mean(axis=0), cycles[central].mean(axis=0), rtol=0.02)
    assert report["sampled"] < 0.05, report
    assert report["own copy only"] > 3 * report["all copies"], report


# --- H2xR and S2xR: every copy in the universal cover, every connecting geodesic -----------------------
# The truth below is written from the product structure alone: the copies from the preset's
# generator matrices (words searched in the test), distances from the hyperboloid's and the sphere's
# textbook formulas, the cosine towards each copy as minus the derivative of that geodesic's length
# along the normal (central differences), the falloff as the wavefront's area density. The tracer's
# copy search (render.cover_copies) and its C++ connections share none of it.


def h2xr_model(x):
    """Chart (x, y, z) -> the model (X1, X2, e^z, X0), (X1, X2, X0) = (x, y, 1) / sqrt(1 - x^2 - y^2)."""
    s = 1 / math.sqrt(1 - x[0] ** 2 - x[1] ** 2)
    return np.array([s * x[0], s * x[1], math.exp(x[2]), s])


def h2xr_chart(X):
    return np.array([X[0] / X[3], X[1] / X[3], math.log(X[2])])


def h2xr_distance(a, b):
    """(horizontal, vertical) distances of chart points: cosh d = (1 - a.b) / sqrt((1 - a^2)(1 - b^2))
    on the disk, and the difference of z."""
    c = (1 - a[0] * b[0] - a[1] * b[1]) / math.sqrt((1 - a[0] ** 2 - a[1] ** 2) * (1 - b[0] ** 2 - b[1] ** 2))
    return math.acosh(max(c, 1.0)), b[2] - a[2]


def deck_elements(space, origin, within, distance_from_origin, rho):
    """The group elements g with distance_from_origin(g) <= within, by a breadth-first search over
    the generators and their inverses that goes on through elements up to rho farther (a geodesic
    to g O passes through tiles whose copies of O lie within rho, the domain's circumradius about
    O, of it); an element is known by its image g O of the model point O (the action is free)."""
    steps = [*space.generators, *(np.linalg.inv(M) for M in space.generators)]
    key = lambda M: tuple(np.round(M @ origin / np.linalg.norm(M @ origin), 8))
    found, frontier = {key(np.eye(4)): np.eye(4)}, [np.eye(4)]
    while frontier:
        nxt = []
        for M in frontier:
            for S in steps:
                N = M @ S
                if key(N) not in found and distance_from_origin(N) <= within + rho:
                    found[key(N)] = N
                    nxt.append(N)
        frontier = nxt
    return [M for M in found.values() if distance_from_origin(M) <= within]


def central_difference(f, x, n, h=1e-6):
    return (f(x + h * n) - f(x - h * n)) / (2 * h)


@pytest.mark.parametrize(
    "sid, reach, facing", [("genus2xs1", 4.5, 15), pytest.param("surface_x_circle(3)", 3.88, 1, marks=pytest.mark.slow)]
)
def test_genus_g_x_circle_sums_every_copy_in_the_cover(sid, reach, facing, tmp_path, monkeypatch):
    """H2xR, genus2xs1 and the genus-3 family member at its default reach (where the render's walk
    to the light's copies passes words of the 12-gon's side translations with entries of 10^4, which
    lose digits in every product unless repaired): a point of a ball lit by a light is lit along the one geodesic to each copy
    g L of the light in H2 x R within the reach (the Fuchsian group's copies times the circle's),
    with cos * p * d / (r^2 sinh d) (the wavefront: H2's circle of radius d = the horizontal length
    times the flat direction; r^2 = d^2 + dz^2), to the float32 colour's precision. Each copy's
    term exceeds the tolerance 50 times over, so a missing copy fails it."""
    monkeypatch.setenv("THURSTON_CACHE_DIR", str(tmp_path))
    space = spaces.load(sid)
    light, power = np.array([0.25, -0.1, 0.6]), 0.8
    centre = np.array([-0.1, 0.3, -0.2])
    colour, H, N, out = shade_one(space, ball_scene(centre, light, power), centre + [0.0, -0.3, 0.1], centre, reach)
    g = space.geometry
    x, n = g.to_chart(H), g.tangent_to_chart(H, N)  # the hit point and its unit normal, as the trace gave them
    L = h2xr_model(light)
    origin = np.array([0.0, 0.0, 1.0, 1.0])
    around = lambda M: math.hypot(*h2xr_distance(np.zeros(3), h2xr_chart(M @ origin)))
    # d(O, gO) <= d(O, x) + reach + d(L, O) for a copy within reach of x
    bound = math.hypot(*h2xr_distance(np.zeros(3), x)) + reach + math.hypot(*h2xr_distance(np.zeros(3), light))
    terms, energy = [], 0.0
    rho = max(math.hypot(*h2xr_distance(np.zeros(3), v)) for v in space.domain.vertices)
    for M in deck_elements(space, origin, bound, around, rho):
        q = h2xr_chart(M @ L)
        d, dz = h2xr_distance(x, q)
        r = math.hypot(d, dz)
        if r > reach:
            continue
        assert reach - r > 1e-6  # no copy on the boundary of the reach
        falloff = d / (r * r * math.sinh(d))
        cosine = -central_difference(lambda p: math.hypot(*h2xr_distance(p, q)), x, n)
        energy += power * falloff * (cosine > 0)  # (the paths to the point's front are counted)
        terms.append(max(cosine, 0.0) * power * falloff)
    terms = np.array(terms)
    assert np.count_nonzero(terms) == out["light_paths"] and np.count_nonzero(terms) > facing
    assert float(out["light_energy"]) == pytest.approx(energy, rel=1e-6)
    rtol = 1e-5  # the colour is float32
    np.testing.assert_allclose(colour, GLOW + RHO * terms.sum(), rtol=rtol)
    print(
        "relative error",
        np.abs(colour / (GLOW + RHO * terms.sum()) - 1).max(),
        "smallest term / colour",
        RHO * terms[terms > 0].min() / colour.max(),
    )
    assert RHO * terms[terms > 0].min() > 50 * rtol * colour.max()  # a missing copy fails it


def s2xs1_copies(light):
    """S^2 x S^1's deck group: the dilations by e^{2 pi k}."""
    return [np.exp(2 * math.pi * k) * light for k in range(-4, 5)]


def rp3_rp3_copies(light):
    """RP^3 # RP^3's: the dilations by e^{4 pi k} (the two reflections composed) and those after the
    inner sphere's antipodal reflection y -> -y / |y|^2, written out here."""
    shifted = [np.exp(4 * math.pi * k) * light for k in range(-3, 4)]
    return shifted + [-q / (q @ q) for q in shifted]


@pytest.mark.parametrize("sid, copies", [("s2xs1", s2xs1_copies), ("rp3_rp3", rp3_rp3_copies)])
def test_s2xr_sums_every_arc_of_every_copy(sid, copies):
    """S2xR, s2xs1 and rp3_rp3: from a point to each copy of the light in the cover (R^3 minus the
    origin) the cover holds one geodesic per great-circle arc between their directions, going
    either way round and winding: sphere angles theta + 2 pi n and 2 pi (n + 1) - theta, with
    r^2 = angle^2 + dw^2 and the falloff angle / (r^2 |sin angle|) (the sphere's circle times the
    flat direction). The sum of cos * p * falloff over those within the reach, against the traced
    colour (in rp3_rp3 the light's reflected copies light the point too)."""
    space = spaces.load(sid)
    light, power, reach = np.array([14.0, -26.0, 9.0]), 0.8, 13.0
    centre = np.array([0.0, -30.0, 0.0])
    scale = np.linalg.norm(centre)  # the metric is |dx| / |x|: a ball of chart radius 0.02 |x|
    ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02 * scale)
    scene = Scene(
        objects=[SceneObject("ball", ball.vertices + centre, ball.faces, (RHO,) * 3, emission=(GLOW,) * 3)],
        lights=[PointLight(light, np.ones(3), power)],
    )
    colour, H, N, out = shade_one(space, scene, centre + [0.0, -0.3 * scale, 0.1 * scale], centre, reach)
    g = space.geometry
    x, n = g.to_chart(H), g.tangent_to_chart(H, N)

    def angle_and_dw(p, q):
        u, v = p / np.linalg.norm(p), q / np.linalg.norm(q)
        return math.atan2(np.linalg.norm(np.cross(u, v)), u @ v), math.log(np.linalg.norm(q) / np.linalg.norm(p))

    terms, energy, arcs = [], 0.0, set()
    cover = copies(light)
    own = next(i for i, q in enumerate(cover) if np.allclose(q, light))
    for k, q in enumerate(cover):
        for n_turns in range(4):
            for way in (+1, -1):  # the arc towards q's direction, or the other way round

                def length(p):
                    theta, dw = angle_and_dw(p, q)
                    return math.hypot(2 * math.pi * n_turns + (theta if way > 0 else 2 * math.pi - theta), dw)

                theta, dw = angle_and_dw(x, q)
                alpha = 2 * math.pi * n_turns + (theta if way > 0 else 2 * math.pi - theta)
                r = math.hypot(alpha, dw)
                if r > reach:
                    continue
                assert reach - r > 1e-6
                arcs.add((k, n_turns, way))
                falloff = alpha / (r * r * abs(math.sin(alpha)))
                cosine = -central_difference(length, x, n)
                energy += power * falloff * (cosine > 0)  # (the paths to the point's front are counted)
                terms.append(max(cosine, 0.0) * power * falloff)
    terms = np.array(terms)
    assert np.count_nonzero(terms) == out["light_paths"]
    assert {
        (own, 0, -1),
        (own, 1, 1),
        (own, 1, -1),
        (own + 1, 0, 1),
        (own - 1, 0, 1),
    } <= arcs  # both ways, winding, other copies
    if sid == "rp3_rp3":
        assert any(k >= len(cover) // 2 for k, _, _ in arcs)  # a reflected copy is within the reach
    assert float(out["light_energy"]) == pytest.approx(energy, rel=1e-6)
    rtol = 1e-5  # the colour is float32
    np.testing.assert_allclose(colour, GLOW + RHO * terms.sum(), rtol=rtol)
    print(
        "relative error",
        np.abs(colour / (GLOW + RHO * terms.sum()) - 1).max(),
        "smallest term / colour",
        RHO * terms[terms > 0].min() / colour.max(),
    )
    assert RHO * terms[terms > 0].min() > 50 * rtol * colour.max()


@pytest.mark.parametrize(
    "sid, light, centre, lamp_radius",
    [
        ("genus2xs1", [0.25, -0.1, 0.6], [-0.1, 0.3, -0.2], 0.05),
        ("s2xs1", [14.0, -26.0, 9.0], [0.0, -30.0, 0.0], 0.05 * 31.0),
    ],
)
def test_a_shut_in_light_is_shadowed_along_every_geodesic(sid, light, centre, lamp_radius):
    """The light inside a closed opaque ball: every geodesic to every copy (the shadow rays cross
    faces, go round the sphere, wind) meets the ball, so only the shaded ball's own emission is left."""
    space = spaces.load(sid)
    scene = ball_scene(np.array(centre), light, 0.8)
    if sid == "s2xs1":  # the metric is |dx| / |x|: balls of chart radius proportional to |x|
        ball = trimesh.creation.icosphere(subdivisions=3, radius=0.02 * np.linalg.norm(centre))
        scene.objects[0] = SceneObject("ball", ball.vertices + centre, ball.faces, (RHO,) * 3, emission=(GLOW,) * 3)
    shell = trimesh.creation.icosphere(subdivisions=2, radius=lamp_radius)
    scene.objects.append(SceneObject("lamp shade", shell.vertices + light, shell.faces, (0.5,) * 3))
    origin = np.array(centre) + np.array([0.0, -0.3, 0.1]) * (np.linalg.norm(centre) if sid == "s2xs1" else 1.0)
    colour, _, _, out = shade_one(space, scene, origin, centre, 4.5 if sid == "genus2xs1" else 13.0)
    assert out["light_paths"] > 5
    # the ball's faint glow is a light too: its copies add 4e-5 (H2xR) to 3e-3 (S2xR, whose
    # spheres focus them) of it; the lamp unshadowed would add over 100 times the glow
    np.testing.assert_allclose(colour, GLOW, rtol=1e-2)
