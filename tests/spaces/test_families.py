"""The families of spaces (lens(p,q), prism(n), binary(...), flat(...), nil(n)) against closed
forms and published invariants: volumes 2π²/|G| and lattice covolumes written here, the group
orders, the first homology (L(p, q): Z/p; the Hantzsche-Wendt manifold: Z/4 + Z/4; the
amphicosms and amphidicosms: Conway and Rossetti's table); the member's file kept in the cache;
an orientation-reversing pairing traced against the straight lines of the universal cover (the
mirrored copies of the scene where the cover has them, with their normals)."""

import math

import numpy as np
import OpenImageIO as oiio
import pytest
import trimesh
from support.textured_quad import texel_centres, textured_quad

from thurston_addon import cli, render, spaces
from thurston_addon.scenes import Scene, SceneObject
from thurston_addon.spaces import families, homology

TWO_PI_SQUARED = 2 * math.pi**2


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("THURSTON_CACHE_DIR", str(tmp_path))
    return tmp_path


def h1(space):
    return homology.homology_text(homology.first_homology(space))


@pytest.mark.parametrize("p, q", [(5, 2), (7, 2), (7, 3), (12, 5), (25, 7)])
def test_lens_spaces(p, q):
    space = spaces.load(f"lens({p},{q})")
    assert space.geometry.name == "S3" and space.group_order == p
    assert space.volume == pytest.approx(TWO_PI_SQUARED / p, rel=1e-9)
    assert h1(space) == f"Z/{p}"
    assert homology.relation_residual(space) < 1e-10


@pytest.mark.parametrize(
    "name, order, published",
    [
        ("prism(2)", 8, "Z/2 + Z/2"),  # the quaternion space
        ("prism(3)", 12, "Z/4"),  # D*_4n: Z/4 for n odd, Z/2 + Z/2 for n even
        ("prism(4)", 16, "Z/2 + Z/2"),
        ("binary(tetrahedral)", 24, "Z/3"),
        ("binary(octahedral)", 48, "Z/2"),
        ("binary(icosahedral)", 120, "0"),  # the Poincaré homology sphere
    ],
)
def test_spherical_quotients(name, order, published):
    space = spaces.load(name)
    assert space.group_order == order
    assert space.volume == pytest.approx(TWO_PI_SQUARED / order, rel=1e-9)
    assert h1(space) == published


# The ten closed flat manifolds: (covolume of the translation lattice, holonomy order, H1 published)
FLAT = {
    "torocosm": (1, 1, "Z + Z + Z"),
    "dicosm": (1, 2, "Z + Z/2 + Z/2"),
    "tricosm": (math.sqrt(3) / 2, 3, "Z + Z/3"),
    "tetracosm": (1, 4, "Z + Z/2"),
    "hexacosm": (math.sqrt(3) / 2, 6, "Z"),
    "didicosm": (1, 4, "Z/4 + Z/4"),  # Hantzsche-Wendt
    "amphicosm1": (1, 2, "Z + Z + Z/2"),
    "amphicosm2": (0.5, 2, "Z + Z"),
    "amphidicosm1": (1, 4, "Z + Z/2 + Z/2"),
    "amphidicosm2": (1, 4, "Z + Z/4"),
}


@pytest.mark.parametrize("which", FLAT)
def test_the_ten_flat_manifolds(which):
    lattice, holonomy, published = FLAT[which]
    space = spaces.load(f"flat({which})")
    assert space.volume == pytest.approx(lattice / holonomy, rel=1e-9)
    assert len(space.holonomy) == holonomy
    orientable = not which.startswith("amphi")
    assert all(np.linalg.det(R) > 0 for R in space.holonomy) == orientable
    assert h1(space) == published


@pytest.mark.parametrize("n", [1, 2, 5])
def test_nil_quotients(n):
    space = spaces.load(f"nil({n})")
    assert space.volume == pytest.approx(1 / n, rel=1e-9)
    x, y, z = space.generators
    commutator = x @ y @ np.linalg.inv(x) @ np.linalg.inv(y)
    assert np.allclose(commutator, np.linalg.matrix_power(z, n))  # the Euler number: [x, y] = z^n
    # <x, y, z | [x, y] z^-n, [x, z], [y, z]>: H1 = Z^2 + Z/n
    relators = [[(0, 1), (1, 1), (0, -1), (1, -1), *[(2, -1)] * n], [(0, 1), (2, 1), (0, -1), (2, -1)]]
    rows = homology.abelianised(homology.Presentation([0, 1, 2], relators))
    assert homology.homology_text(homology.invariant_factors(rows, 3)) == ("Z + Z" + (f" + Z/{n}" if n > 1 else ""))


@pytest.mark.parametrize("a, b, c, d", [(2, 1, 1, 1), (3, 1, 2, 1), (5, 2, 2, 1), (-3, -1, -2, -1), (0, -1, 1, 3)])
def test_sol_torus_bundles(a, b, c, d):
    A = np.array([[a, b], [c, d]])
    space = spaces.load(f"sol({a},{b},{c},{d})")
    # the volume: log λ times the covolume of Z^2 in unit eigenvector coordinates, 1 / |sin| of
    # the angle between A's eigenvectors (closed forms: λ + 1/λ = |tr A|)
    lam = (abs(a + d) + math.sqrt((a + d) ** 2 - 4)) / 2
    v = [np.array([b, lam * np.sign(a + d) - a]), np.array([b, np.sign(a + d) / lam - a])]
    if b == 0:
        v = [np.array([lam * np.sign(a + d) - d, c]), np.array([np.sign(a + d) / lam - d, c])]
    sine = abs(np.cross(v[0], v[1])) / (np.linalg.norm(v[0]) * np.linalg.norm(v[1]))
    assert space.volume == pytest.approx(math.log(lam) / sine, rel=1e-6)
    # the monodromy acts on the lattice as A: t u_j t^-1 = u1^A[0, j] u2^A[1, j]
    u1, u2, t = space.generators
    for j, u in enumerate((u1, u2)):
        image = np.linalg.matrix_power(u1, A[0, j]) @ np.linalg.matrix_power(u2, A[1, j])
        assert np.allclose(t @ u @ np.linalg.inv(t), image, atol=1e-9)
    # <u1, u2, t | [u1, u2], t u_j t^-1 = A u_j>: H1 = Z + coker(A - I), of order |det(A - I)| = |2 - tr A|
    relators = [[(0, 1), (1, 1), (0, -1), (1, -1)]]
    for j in range(2):
        relators.append(
            [
                (2, 1),
                (j, 1),
                (2, -1),
                *[(0, -1)] * A[0, j],
                *[(0, 1)] * -A[0, j],
                *[(1, -1)] * A[1, j],
                *[(1, 1)] * -A[1, j],
            ]
        )
    factors = homology.invariant_factors(homology.abelianised(homology.Presentation([0, 1, 2], relators)), 3)
    assert factors.count(0) == 1 and math.prod(f for f in factors if f) == abs(2 - (a + d))


def surface_relator(g):
    """The regular 4g-gon's boundary word in its side translations A_0..A_2g-1 (opposite sides
    paired): A0 A1^-1 A2 ... A_2g-1^-1 A0^-1 A1 ... A_2g-1 = 1, as (generator, exponent)."""
    half = [(k, 1 if k % 2 == 0 else -1) for k in range(2 * g)]
    return half + [(k, -e) for k, e in half]


@pytest.mark.parametrize("g", [2, pytest.param(3, marks=pytest.mark.slow), pytest.param(4, marks=pytest.mark.slow)])
@pytest.mark.parametrize("family", ["surface_x_circle", "unit_tangent"])
def test_genus_g_bundles(family, g):
    space = spaces.load(f"{family}({g})")
    # (genus-g surface) x S¹: 4π(g - 1) (the 4g-gon's area) times 2 r_in, cosh r_in = cot(π/4g); T¹Σ_g: times 2π
    r = math.acosh(1 / math.tan(math.pi / (4 * g)))
    fibre = 2 * r if family == "surface_x_circle" else 2 * math.pi
    assert space.volume == pytest.approx(4 * math.pi * (g - 1) * fibre, rel=1e-6)
    # the generators hold the surface relation (in SL2~ up to the fibre translation by 4π(g - 1) = ±1 as matrices)
    word = np.eye(4)
    for k, e in surface_relator(g):
        word = word @ np.linalg.matrix_power(space.generators[k], e)
    assert np.allclose(word, np.eye(4), atol=1e-6)  # (rounding: 4g letters of entries up to cosh 2r = 50)
    # H1 from the presentation <A_k, f | relator f^-e, [A_k, f]>, e = 0 (x S¹) or 2 - 2g (Euler number)
    euler = 0 if family == "surface_x_circle" else 2 * g - 2
    f = 2 * g
    relators = [surface_relator(g) + [(f, -1)] * euler] + [[(k, 1), (f, 1), (k, -1), (f, -1)] for k in range(f)]
    rows = homology.abelianised(homology.Presentation(list(range(f + 1)), relators))
    published = " + ".join(["Z"] * (2 * g) + ["Z" if euler == 0 else f"Z/{euler}"])
    assert homology.homology_text(homology.invariant_factors(rows, f + 1)) == published
    if g == 2:  # the presets, written by hand
        reference = spaces.load("genus2xs1" if family == "surface_x_circle" else "sl2")
        assert np.allclose(space.generators, reference.generators, atol=1e-12)


@pytest.mark.slow
@pytest.mark.parametrize("family", ["surface_x_circle", "unit_tangent"])
def test_a_genus_three_view_hits_the_scene(family, tmp_path, capsys):
    """The default view at the default light reach, whose walk to the light's copies passes
    21000 (H2xR) and 31000 (SL2~) of them (render/lights.py's limit), with every tube of the
    default scene inside the copies of the domain the render shows (no warning)."""
    out = tmp_path / "view.exr"
    argv = ["render", "--space", f"{family}(3)", "--size", "24x16", "--samples", "1"]
    assert cli.main([*argv, "--out", str(out)]) == 0
    assert "warning" not in capsys.readouterr().err
    pixels = oiio.ImageBuf(str(out)).get_pixels(oiio.FLOAT)[..., :3]
    assert np.isfinite(pixels).all() and (pixels.sum(axis=-1) > 0).mean() > 0.5  # lit surfaces, most of the view


@pytest.mark.parametrize("g", [3, pytest.param(4, marks=pytest.mark.slow)])
def test_rays_meet_a_wall_beyond_a_face_at_the_closed_form_depth(g):
    """(genus-g surface) x S¹: a wall on the chord x = -1/2 of the disk, behind the camera at the
    centre; rays ahead leave through the side x = tanh r_in and meet the wall's copy under the side
    translation by 2 r_in, the geodesic perpendicular to the x axis at distance δ = 2 r_in -
    atanh(1/2). A horizontal geodesic at angle a meets it at h, tanh δ = tanh h cos a (the right
    triangle), so at depth h sqrt(1 + w^2) rising w per unit (the trace's words reach entries of 10^3)."""
    space = spaces.load(f"surface_x_circle({g})")
    geometry = space.geometry
    r = math.acosh(1 / math.tan(math.pi / (4 * g)))
    wall = np.array([[-0.5, -0.6, -1.0], [-0.5, 0.6, -1.0], [-0.5, 0.6, 1.0], [-0.5, -0.6, 1.0]])
    scene = Scene(objects=[SceneObject("wall", wall, np.array([[0, 1, 2], [0, 2, 3]]), (0.5,) * 3)], lights=[])
    tracer = render.make_tracer(space, scene, threads=1, light_reach=1.0)
    a, w = np.array([-0.01, 0.0, 0.01]), 0.1
    o, d = np.zeros((3, 3)), np.stack([np.cos(a), np.sin(a), np.full(3, w)], 1)
    P = geometry.to_model(o)
    out = tracer.trace(P, geometry.normalize_tangent(P, geometry.tangent_to_model(o, d)), 10.0, 40, shade=False)
    h = np.arctanh(np.tanh(2 * r - math.atanh(0.5)) / np.cos(a))
    assert (out["stop"] == 0).all() and (out["object"] == 0).all()
    np.testing.assert_allclose(out["depth"], h * math.hypot(1, w), rtol=1e-9)
    np.testing.assert_allclose(out["position"][:, 0], -0.5, atol=1e-9)  # on the wall, in the domain


def test_genus_below_two_is_refused():
    with pytest.raises(spaces.SpaceError, match="genus g >= 2"):
        spaces.load("surface_x_circle(1)")


def test_a_member_is_a_file_the_user_keeps(cache):
    spaces.load("lens(7,2)")
    (path,) = (cache / "family").iterdir()
    text = path.read_text()
    assert 'geometry = "S3"' in text and "covolume" in text
    path.write_text(text.replace('name = "L(7, 2)"', 'name = "my lens"'))
    assert spaces.load("lens(7,2)").name == "my lens"  # an edited member is kept, not rewritten
    assert spaces.load(path).group_order == 7


def test_a_wrong_covolume_in_a_dirichlet_file_is_refused(cache, tmp_path):
    text = spaces.named_file("lens(7,2)").read_text()
    wrong = tmp_path / "wrong.toml"
    wrong.write_text("\n".join("covolume = 2.8" if line.startswith("covolume") else line for line in text.splitlines()))
    with pytest.raises(spaces.SpaceError, match="is not the covolume 2.8"):
        spaces.load(wrong)


@pytest.mark.parametrize(
    "name, message",
    [
        ("lens(7,1)", "L\\(7, ±1\\) is not supported: its group acts on C² by scalars"),
        ("lens(7,6)", "a whole orbit at distance π/2"),
        ("lens(2,1)", "L\\(2, ±1\\) = RP³ is not supported"),
        ("lens(6,3)", "q prime to p"),
        ("prism(1)", "n >= 2"),
        ("flat(klein)", "the closed flat manifolds are"),
        ("binary(cubic)", "the binary groups are"),
        ("lens(7)", "takes p, q"),
        ("nil(0)", "positive integer"),
    ],
)
def test_bad_parameters_are_refused(name, message):
    with pytest.raises(spaces.SpaceError, match=message):
        spaces.load(name)


def test_listing_names_the_families(capsys):
    assert cli.main(["spaces"]) == 0
    out = capsys.readouterr().out
    for family in families.FAMILIES:
        assert family.example in out and family.parameters in out


def _cover_elements(space, reach, words=12):
    """The group's elements g with |g(0)| <= reach among the words of up to `words` generators and
    their inverses, closed here from the generators (E3)."""
    found = {}
    frontier = [np.eye(4)]
    steps = [*space.generators, *map(np.linalg.inv, space.generators)]
    for _ in range(words):
        nxt = []
        for M in frontier:
            for s in steps:
                N = s @ M
                key = tuple(np.round(N, 6).ravel() + 0.0)
                if key not in found:
                    found[key] = N
                    nxt.append(N)
        frontier = nxt
    return [M for M in found.values() if np.linalg.norm(M[:3, 3]) <= reach]


@pytest.mark.parametrize("which", ["dicosm", "amphicosm1", "amphidicosm2"])
def test_orientation_reversing_pairings_show_the_mirror_image(which):
    """Rays from inside a non-orientable flat manifold against straight lines in the universal
    cover: a ball inside the domain and one across a face (copied into the domain by a pairing),
    their copies g(ball) (mirrored where det g < 0): the first hit between the circumscribed and
    inscribed spheres' entries, its point and normal those of the ball carried back by g^-1 (and
    into the domain): a mirrored copy shows the mirrored ball."""
    space = spaces.load(f"flat({which})")
    mesh = trimesh.creation.icosphere(subdivisions=4, radius=1.0)
    faces_x = max(v[0] for v in space.domain.vertices)
    balls = [(np.array([0.05, 0.2, 0.15]), 0.12), (np.array([faces_x - 0.03, -0.2, 0.25]), 0.1)]
    objects = [SceneObject(f"ball{i}", mesh.vertices * r + c, mesh.faces) for i, (c, r) in enumerate(balls)]
    inner = math.cos(math.atan(2) / 2**4)  # below an icosphere's inscribed radius (its edges: atan 2 / 2^4)
    rng = np.random.default_rng(5)
    n, length = 400, 2.5
    V = rng.normal(size=(n, 3))
    V /= np.linalg.norm(V, axis=1)[:, None]
    g = space.geometry
    X = np.ascontiguousarray(g.to_model(np.zeros((n, 3))))
    D = np.ascontiguousarray(np.concatenate([V, np.zeros((n, 1))], axis=1))
    tracer = render.make_tracer(space, Scene(objects, [], None), threads=2)
    out = render.trace(tracer, X, D, length, 200, 1e-7, shade=False)
    positions, normals = render.own_hits(space, out)
    elements = _cover_elements(space, length + 1)
    near = [h for h in elements if np.linalg.norm(h[:3, 3]) < 2]  # those that can bring a ball's point into D
    # every copy g(ball): its centre, radius and element, and each ray's entry into each copy's
    # circumscribed and inscribed spheres (inf where it passes by)
    copies = [(M[:3, :3] @ c + M[:3, 3], r, M) for M in elements for c, r in balls]
    G = np.array([gc for gc, _, _ in copies])
    radius = np.array([r for _, r, _ in copies])
    b = V @ G.T
    with np.errstate(invalid="ignore"):
        t_outer = b - np.sqrt(b * b - np.sum(G * G, axis=1) + radius**2)
        t_inner = b - np.sqrt(b * b - np.sum(G * G, axis=1) + (inner * radius) ** 2)
    t_outer = np.where(t_outer > 0, t_outer, np.inf)  # (NaN: passes by)
    first = np.argmin(t_outer, axis=1)
    mirrored = compared = 0
    for i in range(n):
        t_out, t_in = t_outer[i, first[i]], t_inner[i, first[i]]
        gc, _, M = copies[first[i]]
        if t_out > length - 0.05 or not t_in - t_out < 0.02:
            continue  # misses, grazing rays and far hits are not compared
        compared += 1
        assert out["stop"][i] == 0 and t_out - 1e-6 <= out["depth"][i] <= t_in + 1e-6
        hit = out["depth"][i] * V[i]
        own = np.linalg.solve(M, [*hit, 1])  # the point of the ball g^-1 takes the hit to
        n_own = M[:3, :3].T @ (hit - gc) / np.linalg.norm(hit - gc)  # and the sphere's normal there
        # the tracer reports them in the domain: the same point and normal, or (where that point of
        # the ball lies outside the domain) their images under the element h that brings it in
        images = [(h @ own)[:3] for h in near]
        k = int(np.argmin([np.linalg.norm(positions[i] - x) for x in images]))
        assert np.linalg.norm(positions[i] - images[k]) < 1e-3
        assert normals[i] @ (near[k][:3, :3] @ n_own) > 0.99
        mirrored += np.linalg.det(M[:3, :3]) < 0
    assert compared > 100 and (mirrored > 30) == which.startswith("amphi")


def test_text_seen_through_a_glide_reflection_is_mirrored():
    """flat(amphicosm1)'s glide reflection (x, y, z) -> (x + 1/2, y, -z) pairs the faces x = -1/4
    and x = 1/4: a textured quad at x = -0.2 is seen beyond x = 1/4 at x = 0.3, upside down. The
    albedo at the copy's point (0.3, y, -z) is the texel of the quad's point (-0.2, y, z)."""
    space = spaces.load("flat(amphicosm1)")
    quad, texels, plain = textured_quad()  # at x = 0.2; moved to x = -0.2
    quad = SceneObject(
        "quad",
        quad.vertices - [0.4, 0, 0],
        quad.triangles,
        corner_uvs=quad.corner_uvs,
        triangle_material=quad.triangle_material,
        materials=quad.materials,
    )
    targets, rows, cols, textured = texel_centres()  # (0.2, y, z) on the quad
    seen = targets * [1.5, 1, -1]  # (0.3, y, -z): the glide's image of (-0.2, y, z)
    g = space.geometry
    X = g.to_model(np.zeros((len(seen), 3)))
    D = g.normalize_tangent(X, g.tangent_to_model(np.zeros((len(seen), 3)), seen))
    out = render.make_tracer(space, Scene(objects=[quad], lights=[])).trace(X, D, 1.0, 20, shade=True)
    assert np.all(out["stop"] == 0) and np.allclose(out["depth"], np.linalg.norm(seen, axis=1), atol=1e-9)
    expected = np.where(textured[:, None], texels[rows, cols], plain.color)
    np.testing.assert_allclose(out["albedo"], expected, rtol=1e-5)
    unmirrored = np.where(textured[:, None], texels[3 - rows, cols], plain.color)  # what no mirror would show
    assert not np.allclose(out["albedo"], unmirrored, rtol=1e-2)
