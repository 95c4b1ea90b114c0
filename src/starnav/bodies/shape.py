"""Small-body shape models: PDS vertex/facet ``.tab`` files and Wavefront OBJ, read into SI.

* PDS ``.tab`` (``v x y z`` in km, ``f i j k``): the index base is detected (a smallest face
  index of 0 or 1; the Itokawa radar model is 1-based, Basilisk's Eros plates 0-based), and
  every index checked.
* Wavefront OBJ (km, 1-based, with the usual extras) read by trimesh, polygons fan-triangulated.

Both give a :class:`ShapeModel` (vertices in metres, 0-based ``int64`` triangles, its source);
mass properties come from trimesh and exist only for a closed, consistently wound mesh. A bad
file raises :class:`ShapeModelError` naming the file, the line and what was expected, before
anything is rendered. Packaged models: :data:`PACKAGED_SHAPE_MODELS`
(``starnav/data/smallbody/PROVENANCE.md``).

Index
-----
:func:`read_shape_model`, :func:`shape_model_path`, :class:`ShapeModel`,
:class:`ShapeModelError`, :data:`PACKAGED_SHAPE_MODELS`, :data:`SHAPE_SUFFIXES`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np
import trimesh
from numpy.typing import NDArray

from starnav.data import packaged_path
from starnav.errors import ConfigError, DataFileError
from starnav.registry import Registry
from starnav.typing import FloatArray

IntArray = NDArray[np.int64]

#: Kilometres (the unit of every shape-model file) in metres.
KM = 1000.0

#: Packaged shape models by name -> path below ``starnav/data``.
PACKAGED_SHAPE_MODELS: Registry[str] = Registry("packaged shape model", {
    "itokawa": "smallbody/25143itokawa.tab",
    "eros": "smallbody/eros007790.tab",
})

#: File suffixes the reader knows.
SHAPE_SUFFIXES = (".tab", ".obj")


class ShapeModelError(DataFileError):
    """A shape-model file that cannot be read as one: names the file, the line (1-based) and
    what was expected there."""

    def __init__(self, path: str | Path, line: int | None, expected: str) -> None:
        self.path = str(path)
        self.line = line
        where = f"{self.path!r}" + (f", line {line}" if line is not None else "")
        super().__init__(f"shape model {where}: expected {expected}")


@dataclass(frozen=True, eq=False)
class ShapeModel:
    """A triangle mesh of a small body in its body-fixed axes.

    Attributes
    ----------
    vertices : (n, 3) float64
        Vertex positions [m].
    faces : (m, 3) int64
        0-based vertex indices of each triangle (outward normals by the right-hand rule in the
        packaged models; checked by :meth:`volume` being positive).
    source : str
        The file read (or a label).
    """

    vertices: FloatArray
    faces: IntArray
    source: str = "array"
    _mesh: trimesh.Trimesh = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_mesh", trimesh.Trimesh(self.vertices, self.faces,
                                                          process=False, validate=False))

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

    @property
    def extents(self) -> FloatArray:
        """Axis-aligned extents along the body x, y, z axes [m]."""
        return np.ptp(self.vertices, axis=0)

    @property
    def bounding_radius(self) -> float:
        """Largest vertex distance from the body origin [m] (every surface point is inside)."""
        return float(np.linalg.norm(self.vertices, axis=1).max())

    @property
    def is_closed(self) -> bool:
        """Every edge shared by exactly two faces, wound consistently (a closed surface)."""
        return bool(self._mesh.is_watertight and self._mesh.is_winding_consistent)

    def _require_closed(self, what: str) -> None:
        if not self.is_closed:
            raise ShapeModelError(self.source, None,
                                  f"a closed, consistently wound mesh for its {what} (every "
                                  "edge shared by exactly two faces); this one is open")

    @property
    def volume(self) -> float:
        """Enclosed volume [m^3] (divergence theorem); :class:`ShapeModelError` if the mesh is
        not closed or is wound inside-out (negative volume)."""
        self._require_closed("volume")
        v = float(self._mesh.volume)
        if v <= 0:
            raise ShapeModelError(self.source, None, "faces wound counter-clockwise seen from "
                                  f"outside (outward normals); the signed volume is {v:.4g} m^3")
        return v

    @property
    def centre_of_mass(self) -> FloatArray:
        """Centre of mass of a uniform body [m] (closed meshes only)."""
        self._require_closed("centre of mass")
        return np.asarray(self._mesh.center_mass, float)

    @property
    def inertia_per_mass(self) -> FloatArray:
        """Inertia tensor per unit mass of a uniform body about its centre of mass, in the
        body axes [m^2] (closed meshes only)."""
        vol = self.volume
        return np.asarray(self._mesh.moment_inertia, float) / vol  # trimesh: density 1

    @cached_property
    def vertex_normals(self) -> FloatArray:
        """Unit vertex normals: the area-weighted mean of the adjacent face normals (smooth
        shading of the facets; the silhouette is the facets' own)."""
        fn = np.cross(self.vertices[self.faces[:, 1]] - self.vertices[self.faces[:, 0]],
                      self.vertices[self.faces[:, 2]] - self.vertices[self.faces[:, 0]])
        n = np.zeros_like(self.vertices)
        for k in range(3):
            np.add.at(n, self.faces[:, k], fn)
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return n / np.where(norm > 0, norm, 1.0)

    def equivalent_ellipsoid_radii(self) -> tuple[float, float, float]:
        """Semi-axes [m] of the uniform ellipsoid with this body's moments of inertia about the
        body x, y, z axes (the dynamically equivalent equal-volume ellipsoid, DEEVE, when the
        axes are principal axes)::

            a^2 = 5/2 (J_yy + J_zz - J_xx),  b^2 = 5/2 (J_xx + J_zz - J_yy),
            c^2 = 5/2 (J_xx + J_yy - J_zz)

        with ``J`` the inertia per unit mass (an ellipsoid has ``J_xx = (b^2 + c^2) / 5``).
        The products of inertia are ignored: for a model whose axes are not principal axes
        (the Eros plate model is in the IAU body frame) this is the ellipsoid of the diagonal.
        """
        J = np.diag(self.inertia_per_mass)
        sq = 2.5 * np.array([J[1] + J[2] - J[0], J[0] + J[2] - J[1], J[0] + J[1] - J[2]])
        if np.any(sq <= 0):
            raise ShapeModelError(self.source, None, "moments of inertia of a solid body "
                                  "(triangle inequality J_xx <= J_yy + J_zz)")
        a, b, c = np.sqrt(sq)
        return (float(a), float(b), float(c))


# ------------------------------------------------------------------------------- readers
def _parse_vertex_facet(path: Path) -> tuple[FloatArray, IntArray]:
    """``v``/``f`` records of a PDS ``.tab`` file (module docstring), vertices in km."""
    verts: list[tuple[float, float, float]] = []
    faces: list[tuple[int, int, int]] = []
    face_lines: list[int] = []
    try:
        text = path.read_text(encoding="ascii")
    except UnicodeDecodeError as err:
        raise ShapeModelError(path, None, f"an ASCII vertex/facet table ({err.reason} at "
                              f"byte {err.start})") from None
    for no, raw in enumerate(text.splitlines(), start=1):
        tok = raw.split()
        if not tok:
            continue
        kind = tok[0].lower()
        if kind not in ("v", "f") or len(tok) != 4:
            raise ShapeModelError(path, no, "'v x y z' (km) or 'f i j k' (vertex indices), got "
                                  f"{raw.strip()[:60]!r}")
        if kind == "v":
            if faces:
                raise ShapeModelError(path, no, "every 'v' record before the first 'f' record "
                                      "(the PDS vertex table precedes the facet table)")
            try:
                x, y, z = (float(t) for t in tok[1:])
            except ValueError:
                raise ShapeModelError(path, no, f"three numbers after 'v', got {raw.strip()!r}"
                                      ) from None
            if not all(np.isfinite((x, y, z))):
                raise ShapeModelError(path, no, f"finite coordinates, got {raw.strip()!r}")
            verts.append((x, y, z))
        else:
            try:
                i, j, k = (int(t) for t in tok[1:])
            except ValueError:
                raise ShapeModelError(path, no, "three integer vertex indices after 'f', got "
                                      f"{raw.strip()!r}") from None
            faces.append((i, j, k))
            face_lines.append(no)
    if len(verts) < 4:
        raise ShapeModelError(path, None, f"at least 4 'v' records, found {len(verts)}")
    if not faces:
        raise ShapeModelError(path, None, "'f i j k' facet records after the vertices, found "
                              "none")
    f = np.asarray(faces, np.int64)
    lo = int(f.min())
    if lo not in (0, 1):
        bad = int(np.argmin(f.min(axis=1)))
        raise ShapeModelError(path, face_lines[bad], "vertex indices numbered from 0 or from "
                              f"1 (the smallest index in the file is {lo})")
    f -= lo
    over = np.flatnonzero(f.max(axis=1) >= len(verts))
    if over.size:
        k = int(over[0])
        raise ShapeModelError(path, face_lines[k], f"vertex indices {lo}..{len(verts) - 1 + lo} "
                              f"({len(verts)} vertices, {lo}-based), got "
                              f"{tuple(int(x) + lo for x in f[k])}")
    return np.asarray(verts, float), f


def _parse_obj(path: Path) -> tuple[FloatArray, IntArray]:
    """Vertices [km] and triangles of a Wavefront OBJ file (trimesh's reader)."""
    try:
        mesh = trimesh.load(path, file_type="obj", force="mesh", process=False,
                            maintain_order=True)
    except Exception as err:  # noqa: BLE001 - trimesh raises many types for a bad file
        raise ShapeModelError(path, None, f"a Wavefront OBJ mesh ({type(err).__name__}: "
                              f"{err})") from None
    v = np.asarray(getattr(mesh, "vertices", np.zeros((0, 3))), float)
    f = np.asarray(getattr(mesh, "faces", np.zeros((0, 3))), np.int64)
    if v.shape[0] < 4 or f.shape[0] == 0:
        raise ShapeModelError(path, None, f"'v' and 'f' records of a triangle mesh, found "
                              f"{v.shape[0]} vertices and {f.shape[0]} faces")
    if not np.all(np.isfinite(v)):
        raise ShapeModelError(path, None, "finite vertex coordinates")
    return v, f


def read_shape_model(path: str | Path) -> ShapeModel:
    """Read a shape model (``.tab`` PDS vertex/facet or ``.obj``; km in the file) into a
    :class:`ShapeModel` in metres.

    Raises
    ------
    ShapeModelError
        The file is missing, has an unknown suffix, a malformed record, an index out of range,
        no faces, or degenerate faces (zero area); the message names the file and the line.
    """
    p = Path(path)
    if not p.is_file():
        raise ShapeModelError(p, None, "an existing shape-model file (.tab or .obj)")
    suffix = p.suffix.lower()
    if suffix == ".tab":
        v_km, f = _parse_vertex_facet(p)
    elif suffix == ".obj":
        v_km, f = _parse_obj(p)
    else:
        raise ShapeModelError(p, None, f"a file suffix in {SHAPE_SUFFIXES}, got {suffix!r}")
    v = v_km * KM
    area2 = np.linalg.norm(np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]]), axis=1)
    degenerate = np.flatnonzero(area2 <= 1e-12 * float(np.ptp(v, axis=0).max()) ** 2)
    if degenerate.size:
        k = int(degenerate[0])
        raise ShapeModelError(p, None, f"triangles of non-zero area; face {k} (0-based, "
                              f"vertices {tuple(int(x) for x in f[k])}) is degenerate "
                              f"({degenerate.size} such faces)")
    return ShapeModel(v, f, str(p))


def shape_model_path(model: str | Path) -> Path:
    """The file of ``model``: a packaged model's name (:data:`PACKAGED_SHAPE_MODELS`) or a
    path to a ``.tab``/``.obj`` file."""
    name = str(model)
    if name in PACKAGED_SHAPE_MODELS:
        return packaged_path(PACKAGED_SHAPE_MODELS.get(name))
    p = Path(name)
    if p.suffix.lower() not in SHAPE_SUFFIXES:
        raise ConfigError("target.model", name, f"one of {PACKAGED_SHAPE_MODELS.names()} or a "
                          f"path to a {'/'.join(SHAPE_SUFFIXES)} shape-model file")
    return p


# ----------------------------------------------------------------------------- coarse models
@dataclass(frozen=True)
class CoarseShape:
    """A coarse model of a shape (:func:`coarse_shape_model`) and how far it is from it.

    Attributes
    ----------
    shape : ShapeModel
        The coarse model, scaled to the original's volume.
    height_rms, height_max : float
        Distance of the original's vertices from the coarse surface, rms and largest [m].
    mean_radius : float
        Radius of the sphere of the original's volume [m].
    """

    shape: ShapeModel
    height_rms: float
    height_max: float
    mean_radius: float


def coarse_shape_model(shape: ShapeModel, faces: int, smoothing_iterations: int
                       ) -> CoarseShape:
    """A coarse, smoothed model of ``shape``: quadric decimation to about ``faces`` triangles
    (VTK's ``vtkQuadricDecimation`` through PyVista, Garland & Heckbert 1997), then Taubin
    smoothing (Taubin 1995; lambda 0.5, mu -0.53: no shrinkage) over ``smoothing_iterations``
    passes, then scaled to the original's volume (what such a model would be before a fly-by:
    the shape at a coarser resolution, its size a separate uncertainty). The result is closed
    and consistently wound."""
    import pyvista as pv  # lazy: PyVista/VTK (heavy)

    if not 4 <= faces < shape.n_faces:
        raise ConfigError("navigation.trn.shape_model.faces", faces,
                          f"4 <= faces < the model's {shape.n_faces} faces")
    if smoothing_iterations < 0:
        raise ConfigError("navigation.trn.shape_model.smoothing_iterations",
                          smoothing_iterations, ">= 0")
    volume = shape.volume
    cells = np.c_[np.full(shape.n_faces, 3), shape.faces].ravel()
    full = pv.PolyData(np.asarray(shape.vertices, float), cells)
    dec = full.decimate(1.0 - faces / shape.n_faces, volume_preservation=True)
    mesh = trimesh.Trimesh(np.asarray(dec.points, float),
                           np.asarray(dec.faces).reshape(-1, 4)[:, 1:], process=False)
    if smoothing_iterations:
        trimesh.smoothing.filter_taubin(mesh, lamb=0.5, nu=0.53,
                                        iterations=int(smoothing_iterations))
    V = np.asarray(mesh.vertices, float)
    V *= (volume / abs(float(mesh.volume))) ** (1.0 / 3.0)
    F = np.asarray(mesh.faces, np.int64)
    coarse = ShapeModel(V, F, f"{shape.source} (coarse: {F.shape[0]} faces, "
                        f"{smoothing_iterations} smoothing passes)")
    coarse._require_closed("use as a coarse model")
    dist = np.abs(np.asarray(full.compute_implicit_distance(
        pv.PolyData(V, np.c_[np.full(F.shape[0], 3), F].ravel()))["implicit_distance"]))
    return CoarseShape(coarse, float(np.sqrt(np.mean(dist**2))), float(dist.max()),
                       float((3.0 * volume / (4.0 * np.pi)) ** (1.0 / 3.0)))
