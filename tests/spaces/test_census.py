"""SnapPy's manifolds as spaces (snappy:NAME) against SnapPy's own numbers and published
invariants: the Weeks manifold's domain (18 faces, 26 vertices, in- and out-radius 0.5192 and
0.7525, volume 0.942707362777), volumes to 1e-8, the edge cycles' relations to 1e-10, the first
homology from the Smith normal form against SnapPy's homology(); the refusals; the first homology
of the flat and spherical presets against the published groups."""

import math
import subprocess
import sys
import tomllib

import pytest
import snappy

from thurston_addon import cli, spaces
from thurston_addon.spaces import homology

WEEKS_VOLUME = 0.942707362777  # the Weeks manifold, the smallest closed hyperbolic 3-manifold


@pytest.fixture(autouse=True)
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("THURSTON_CACHE_DIR", str(tmp_path))
    return tmp_path


def test_weeks_manifold_is_snappys_dirichlet_domain(cache):
    space = spaces.load("snappy:m003(-3,1)")
    assert space.geometry.name == "H3" and space.id == "snappy:m003(-3,1)"
    assert (len(space.domain.faces), len(space.domain.vertices)) == (18, 26)
    assert space.inradius == pytest.approx(0.5192, abs=1e-4)
    assert space.circumradius == pytest.approx(0.7525, abs=1e-4)
    assert space.volume == pytest.approx(WEEKS_VOLUME, abs=1e-11)
    assert abs(space.volume - float(snappy.Manifold("m003(-3,1)").volume())) < 1e-8
    assert homology.relation_residual(space) < 1e-10
    assert homology.homology_text(homology.first_homology(space)) == "Z/5 + Z/5"
    # the space file is in the cache, a file like any other (loaded again without SnapPy's work)
    (written,) = (cache / "snappy").iterdir()
    data = tomllib.loads(written.read_text())
    assert data["geometry"] == "H3" and data["covolume"] == pytest.approx(WEEKS_VOLUME, abs=1e-11)
    again = spaces.load(written)
    assert again.volume == pytest.approx(space.volume, abs=1e-14)
    assert spaces.load("snappy:weeks").volume == pytest.approx(WEEKS_VOLUME, abs=1e-11)


@pytest.mark.parametrize("name", ["m004(5,1)", "m003(-2,3)", "m007(3,1)", "closed:17", "s594(-3,1)"])
def test_census_manifolds_against_snappy(name):
    M = snappy.Manifold(str(snappy.OrientableClosedCensus[17]) if name.startswith("closed:") else name)
    space = spaces.load(f"snappy:{name}")
    assert abs(space.volume - float(M.volume())) < 1e-8
    assert homology.relation_residual(space) < 1e-10
    ours = homology.first_homology(space)
    assert sorted(ours) == sorted(M.homology().coefficients)
    D = M.dirichlet_domain(centroid_at_origin=False)
    assert (len(space.domain.faces), len(space.domain.vertices)) == (D.num_faces(), D.num_vertices())


def test_quad_double_where_double_is_not_enough(cache):
    # closed:600: SnapPy's double-precision pairings satisfy the edge relations only to about 2e-9
    space = spaces.load("snappy:closed:600")
    head = open(space.source).read().split("\n[")[0]
    assert "(quad-double precision)" in head and "the edge cycles' relations hold only to" in head
    assert homology.relation_residual(space) < 1e-10
    M = snappy.ManifoldHP(str(snappy.OrientableClosedCensus[600]))
    assert abs(space.volume - float(M.volume())) < 1e-8


def test_neither_precision_is_refused_with_both_reasons():
    # m004(1,0) is the 3-sphere: SnapPy's "solution" is no hyperbolic structure, no domain fits it
    with pytest.raises(spaces.SpaceError, match="neither precision.*double precision.*SnapPy cannot compute"):
        spaces.load("snappy:m004(1,0)")


@pytest.mark.parametrize(
    "name, message",
    [
        ("m004", "cusped manifolds are not supported"),
        ("m004(0,0)", "cusped manifolds are not supported"),
        ("m004(2,4)", "not of two coprime integers"),
        ("nonsense", "SnapPy does not know this manifold"),
        ("closed:99999", "indexed 0 to 11030"),
    ],
)
def test_refused_with_the_reason(name, message):
    with pytest.raises(spaces.SpaceError, match=message):
        spaces.load(f"snappy:{name}")


def test_command_line_renders_a_census_manifold(tmp_path, capsys):
    out = tmp_path / "weeks.png"
    assert cli.main(["render", "--space", "snappy:m003(-3,1)", "--size", "32x18", "--out", str(out)]) == 0
    assert out.is_file() and "snappy:m003(-3,1)" in capsys.readouterr().out


def test_without_snappy_one_error_names_the_extra(cache):
    # SnapPy made unimportable in a fresh interpreter (None in sys.modules: import raises ImportError)
    code = (
        "import sys; sys.modules['snappy'] = None\n"
        "from thurston_addon import spaces\n"
        "try:\n    spaces.load('snappy:m003(-3,1)')\n"
        "except spaces.SpaceError as exc:\n    print(exc)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert "'census' extra" in proc.stdout and "pip install 'thurston[census]'" in proc.stdout


@pytest.mark.parametrize(
    "preset, published",
    [
        ("torus", "Z + Z + Z"),
        ("half_turn", "Z + Z/2 + Z/2"),
        ("quarter_turn", "Z + Z/2"),
        ("third_turn", "Z + Z/3"),
        ("sixth_turn", "Z"),
        ("hantzsche_wendt", "Z/4 + Z/4"),
        ("poincare", "0"),  # a homology sphere
        ("seifert_weber", "Z/5 + Z/5 + Z/5"),
    ],
)
def test_first_homology_of_the_presets(preset, published):
    space = spaces.load(preset)
    assert homology.homology_text(homology.first_homology(space)) == published
    assert homology.relation_residual(space) < 1e-10


def test_smith_normal_form():
    # Z^3 / <(2,4,4), (-6,6,12), (10,-4,-16)>: the textbook example, diag(2, 6, 12)
    assert homology.invariant_factors([[2, 4, 4], [-6, 6, 12], [10, -4, -16]], 3) == [2, 6, 12]
    assert homology.invariant_factors([[2, 0], [0, 3]], 2) == [6]  # Z/2 + Z/3 = Z/6
    assert homology.invariant_factors([[0, 0, 0]], 3) == [0, 0, 0]
    assert homology.invariant_factors([], 1) == [0]
    assert math.prod(homology.invariant_factors([[4, 6], [6, 4]], 2)) == 20  # |det|
