"""The geometry contract: what every geometry provides, and nothing else.

A geometry works on points and tangent vectors as homogeneous 4-vectors ("model" coordinates) with a
chart of R^3 (mostly x = X[:3] / X[3]), and on isometries as 4x4 matrices acting linearly on model
vectors, so that words in a group's generators are matrix products. Everything broadcasts over
leading axes. The members are grouped: chart, metric, geodesics, isometries, distance bounds,
light, faces; `name` is what a space file's `geometry` field says, `kernel` the C++ core's kernel
that traces it (src/core: the core picks its kernel by this name). Geometries with closed forms
also offer `distance` and `connect` (the shortest geodesic between two points), which Dirichlet
domains and the tests' references use; SL2's light paths are the core's alone.

Implementations: shared.SharedGeometry writes the members most geometries share once;
projective.ProjectiveGeometry (E3, S3, H3) and affine.AffineGeometry (Nil, Sol, S2xR) the families';
H2xR and SL2 their own. Adding a geometry: a subclass that implements every abstract member, the
registry (geometries/__init__.py), a kernel of the core (or an existing one, by `kernel`), a preset;
tests/geometries/test_contract.py then checks it with the others.
"""

from __future__ import annotations

import abc


class Geometry(abc.ABC):
    """The contract. Data members are abstract properties: a subclass satisfies them with class
    attributes or properties."""

    @property
    @abc.abstractmethod
    def name(self) -> str:
        """The geometry's name in space files ("E3", "Nil", ...)."""

    @property
    @abc.abstractmethod
    def kernel(self) -> str:
        """The name of the C++ core's kernel that traces this geometry (thurston_core's registry)."""

    # --- chart ----------------------------------------------------------------------------------
    @abc.abstractmethod
    def to_chart(self, X):
        """Chart points (..., 3) of model points X (..., 4)."""

    @abc.abstractmethod
    def to_model(self, x):
        """Model points (..., 4), normalised, of chart points x (..., 3)."""

    @abc.abstractmethod
    def in_chart(self, x):
        """Whether chart points are points of the geometry (H3: inside the unit ball)."""

    @abc.abstractmethod
    def tangent_to_model(self, x, u):
        """Model tangent vectors of chart vectors u at chart points x (the differential of to_model)."""

    @abc.abstractmethod
    def tangent_to_chart(self, X, V):
        """Chart vectors of model tangent vectors V at model points X (the differential of to_chart)."""

    @abc.abstractmethod
    def normalize_point(self, X):
        """Model vectors put back on the model (removes rounding; keeps extended precision)."""

    @abc.abstractmethod
    def normalize_tangent(self, X, V):
        """V made tangent at X and of unit length in the metric."""

    @abc.abstractmethod
    def charted(self, Y):
        """Whether model vectors are points of the chart (S3: its hemisphere X[3] > 0)."""

    @abc.abstractmethod
    def mesh_to_chart(self, Y):
        """Chart points of a small connected mesh's model vertices (SL2: on one branch of phi)."""

    # --- metric ---------------------------------------------------------------------------------
    @abc.abstractmethod
    def metric(self, x):
        """The chart metric g_ij at chart points x: (..., 3, 3)."""

    @abc.abstractmethod
    def christoffel(self, x):
        """Christoffel symbols of the chart metric at chart points x: (..., 3, 3, 3), [k, i, j] = Gamma^k_ij."""

    @abc.abstractmethod
    def volume_density(self, x):
        """sqrt(det g) of the chart metric at chart points x."""

    @abc.abstractmethod
    def dot(self, X, A, B):
        """The metric at model points X on model tangent vectors A, B."""

    # --- geodesics ------------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def projective(self) -> bool:
        """Whether geodesics are chart lines and bisectors chart planes (E3, S3, H3): the rays are
        exact and spaces may be Dirichlet domains, which use ProjectiveGeometry's bisector,
        dihedral_angle, plane_distances, plane_distance and cone_radial_integral."""

    @property
    @abc.abstractmethod
    def antipode_distance(self) -> float:
        """The arclength after which every geodesic from X reaches the model vector -X (S3: pi);
        inf where none does. A group holding -I then closes every geodesic at that length."""

    @property
    @abc.abstractmethod
    def reference_depth(self) -> float:
        """How deep `geodesic` in the universal cover is a reference (inf: at any depth)."""

    @property
    @abc.abstractmethod
    def chord_scale(self) -> float:
        """The chord tolerance of a quality in units of its error bound (render.Settings.tolerances):
        1 where the chords' bound K h^2 / 8 keeps silhouettes within the bound; up to 4 where the
        error/time front shows every quality within half its bound at it (docs/front.md)."""

    @abc.abstractmethod
    def geodesic(self, P, V, t):
        """Model position and unit velocity at arclength t along the geodesic from the model point P
        with unit tangent V (extended precision is kept where the input has it)."""

    def geodesic_path(self, P, V, length):
        """The geodesic from the model point P with unit tangent V as a function of arclength s in
        [0, length] (arrays of s to model points): geodesic() at each s; a geometry whose geodesics
        are integrated gives one dense solution instead, for callers that ask for many s."""
        return lambda s: self.geodesic(P[None], V[None], s)[0]

    @abc.abstractmethod
    def chart_geodesic(self, x, u, t):
        """Chart position and chart velocity at arclength t from chart point x, chart direction u."""

    @abc.abstractmethod
    def chord_distance(self, A, B):
        """The distance of nearby model points to first order."""

    # --- isometries -----------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def affine_isometries(self) -> bool:
        """Whether every isometry M maps chart points affinely, as M on (x, 1) (E3, Nil, Sol, S2xR):
        copies of an instanced mesh are then instances themselves."""

    @property
    @abc.abstractmethod
    def copy_rings(self) -> int:
        """Rings of neighbouring domains searched for the parts of large objects."""

    @abc.abstractmethod
    def is_isometry(self, M, tol=1e-9) -> bool:
        """Whether the 4x4 matrix M is an isometry of the model."""

    @abc.abstractmethod
    def reorthonormalize(self, M):
        """The exact isometry nearest the almost-isometry M (removes accumulated rounding)."""

    @abc.abstractmethod
    def repair_products(self, M):
        """Products of isometries (..., 4, 4), as walks through the cover build them step by step,
        made exact again where this geometry's products drift (H2xR's), else unchanged."""

    @abc.abstractmethod
    def point_coordinates(self, X):
        """Coordinates (rows) of model points X in which distinct points differ by more than a few
        digits of rounding (the copies of a light are told apart by them): the direction of the
        model vector, or what keeps a geometry's far copies apart where that does not."""

    @abc.abstractmethod
    def element_key(self, M) -> tuple:
        """A hashable key that tells group elements apart (to rounding)."""

    @abc.abstractmethod
    def transform_points(self, M, x):
        """Isometries M applied to chart points x."""

    @abc.abstractmethod
    def generator_problem(self, M) -> str | None:
        """Why a space file may not use the isometry M as a generator (None: it may)."""

    # --- distance bounds ------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def diameter(self) -> float:
        """The largest distance between two points (S3: pi; inf where unbounded)."""

    @property
    @abc.abstractmethod
    def light_reach_circumradii(self) -> float:
        """The default light reach in circumradii of the domain (render.default_light_reach)."""

    @abc.abstractmethod
    def distance_bound(self, A, B):
        """An upper bound of the distance between model points A and B."""

    @abc.abstractmethod
    def farthest_distance(self, X, domain) -> float:
        """An upper bound of the largest distance from the model point X to a domain's points."""

    @abc.abstractmethod
    def domain_distance(self, X, domain):
        """A lower bound of the distances from model points X (..., 4) to a domain."""

    # --- light ----------------------------------------------------------------------------------
    # Whether point lights (and the lambert shading that sums them) are rendered: the graph
    # geometry has no practical light paths and renders the pseudo-colour shadings only.
    point_lights: bool = True

    @abc.abstractmethod
    def falloff_along(self, P, V, r):
        """The falloff of a point light at P seen at distance r along the geodesic (P, V):
        1 / (r^2 |det d exp_P(r V)|) in orthonormal frames."""

    # --- open spaces (a space file without generators: all of the chart, graph's R^3) ------------
    # Whether the geometry has open spaces (open_torus); a space of another needs a group.
    open_spaces: bool = False

    def open_torus(self, reach: float):
        """(geometry, H) for a space that is all of the chart (R^3), seen from points within `reach`
        of the chart origin (chart, along each axis): the geometry repeated on the lattice 2H Z^3,
        H >= reach, equal to the chart's own wherever those points' geodesics go (no ray leaves the
        cube |x_i| <= H, whose torus the spaces layer traces: spaces/open_space.py); ValueError
        naming what keeps the geometry's parameters from it."""
        raise ValueError(f"{self.name} has no open spaces: give its space's generators")

    # --- parameters (a geometry made from its space file's table: graph) -----------------------
    # The space file's table of the geometry's parameters; None: it takes none.
    parameter_table: str | None = None

    def with_parameters(self, table, where):
        """The geometry that the space file's parameter table makes (ValueError naming `where` and
        the key on bad input); the registry's own instance where it takes none."""
        return self

    def check_group(self, generators, where):
        """ValueError naming `where` where the parameters are not invariant under a generator (a
        geometry without parameters: every isometry keeps it)."""
        return None

    @property
    def kernel_parameters(self):
        """The parameters as the core's kernel reads them (a flat list of floats; empty: none)."""
        return ()

    # --- faces ----------------------------------------------------------------------------------
    @property
    @abc.abstractmethod
    def face_shape(self):
        """The shape of a domain's faces in the chart (a faces.FaceShape): chart planes, spheres,
        planes of another chart."""

    @property
    @abc.abstractmethod
    def volume_order(self) -> int:
        """Gauss-Legendre points per axis of a coordinate domain's volume integral."""

    @abc.abstractmethod
    def plane_coordinates(self, X):
        """The homogeneous vectors Y (..., 4) of model points X that face covectors c pair with:
        a face is c . Y = 0, the domain on the side <= 0; y = Y[:3] / Y[3] is the plane chart."""

    @abc.abstractmethod
    def from_plane_chart(self, y):
        """Chart points of plane-chart points y."""

    @abc.abstractmethod
    def plane_chart_density(self, y):
        """The volume density in the plane chart."""

    @abc.abstractmethod
    def pull_back_plane(self, c, M):
        """The covector of the face that the isometry M maps onto the face c (ValueError where M
        maps it onto no face)."""
