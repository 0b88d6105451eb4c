"""Triangle meshes from files, for display (`Visual` records of robot loaders): STL (binary and ASCII) and
Wavefront OBJ by the small readers here, Collada (.dae) through `pycollada` when it is installed (the
`[robots]` extra). Vertices in metres as the file gives them (a Collada file's <unit> applied), faces as
triangles (polygons fanned), and a Collada file's own colour for a visual the URDF gives none.
"""

from __future__ import annotations

import os
import warnings
from dataclasses import dataclass

import numpy as np

MESH_EXTENSIONS = (".stl", ".obj", ".dae")


@dataclass
class Mesh:
    """Triangles: vertices (k, 3) float64 (m), faces (f, 3) int64, and the file's own colour (RGBA) if it has
    one (Collada materials)."""

    vertices: np.ndarray
    faces: np.ndarray
    rgba: tuple[float, float, float, float] | None = None


class MeshError(ValueError):
    """A mesh file that cannot be read; the message names the file and why."""


def read_mesh(path: str) -> Mesh:
    """The triangle mesh in the file at `path`."""
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS:
        raise MeshError(f"{path}: {ext or 'no extension'} meshes are not read (STL, OBJ and Collada are)")
    if not os.path.isfile(path):
        raise MeshError(f"{path}: no such file")
    reader = {".stl": _read_stl, ".obj": _read_obj, ".dae": _read_dae}[ext]
    mesh = reader(path)
    if not len(mesh.faces):
        raise MeshError(f"{path}: the mesh has no triangles")
    if not np.isfinite(mesh.vertices).all():
        raise MeshError(f"{path}: a vertex is NaN or Inf")
    return mesh


def _read_stl(path: str) -> Mesh:
    """Binary STL (80-byte header, a count, 50 bytes a triangle) or ASCII ("solid ... facet ... vertex")."""
    with open(path, "rb") as f:
        data = f.read()
    if len(data) >= 84:
        count = int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])
        if len(data) == 84 + 50 * count:
            record = np.dtype([("normal", "<f4", 3), ("v", "<f4", (3, 3)), ("attr", "<u2")])
            tri = np.frombuffer(data, dtype=record, count=count, offset=84)["v"].astype(np.float64)
            return Mesh(tri.reshape(-1, 3), np.arange(3 * count, dtype=np.int64).reshape(-1, 3))
    if not data.lstrip().lower().startswith(b"solid"):
        raise MeshError(f"{path}: neither a binary STL (size does not match its triangle count) nor an ASCII one")
    words = data.split()
    at = [i for i, w in enumerate(words) if w == b"vertex"]
    try:
        vertices = np.array([[float(words[i + k]) for k in (1, 2, 3)] for i in at], dtype=np.float64)
    except (ValueError, IndexError):
        raise MeshError(f"{path}: a malformed ASCII STL vertex") from None
    if len(vertices) % 3:
        raise MeshError(f"{path}: {len(vertices)} ASCII STL vertices are not whole triangles")
    return Mesh(vertices.reshape(-1, 3), np.arange(len(vertices), dtype=np.int64).reshape(-1, 3))


def _read_obj(path: str) -> Mesh:
    """The 'v' and 'f' lines of a Wavefront OBJ (negative indices relative, polygons fanned into triangles)."""
    vertices: list[list[float]] = []
    faces: list[tuple[int, int, int]] = []
    with open(path, encoding="utf-8", errors="replace") as f:
        for number, line in enumerate(f, 1):
            parts = line.split()
            if not parts:
                continue
            try:
                if parts[0] == "v":
                    vertices.append([float(x) for x in parts[1:4]])
                elif parts[0] == "f":
                    idx = [int(p.split("/")[0]) for p in parts[1:]]
                    idx = [i - 1 if i > 0 else len(vertices) + i for i in idx]
                    faces.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, len(idx) - 1))
            except ValueError:
                raise MeshError(f"{path}:{number}: malformed {parts[0]!r} line") from None
    v = np.array(vertices, dtype=np.float64).reshape(-1, 3)
    fc = np.array(faces, dtype=np.int64).reshape(-1, 3)
    if len(fc) and (fc.min() < 0 or fc.max() >= len(v)):
        raise MeshError(f"{path}: a face indexes a vertex that does not exist ({len(v)} vertices)")
    return Mesh(v, fc)


def _read_dae(path: str) -> Mesh:
    """The triangles of a Collada scene, each placed by its node transforms and scaled by the <unit>, and the
    diffuse colour of the material that covers most of them (a mesh takes one colour)."""
    try:
        import collada
        from collada.common import DaeBrokenRefError, DaeUnsupportedError
    except ImportError:
        raise MeshError(f"{path}: Collada needs pycollada (pip install 'warpimpulse[robots]')") from None
    try:
        with warnings.catch_warnings():  # pycollada builds numpy.matrix objects (a PendingDeprecationWarning each)
            warnings.simplefilter("ignore", PendingDeprecationWarning)
            doc = collada.Collada(path, ignore=[DaeUnsupportedError, DaeBrokenRefError])
    except Exception as exc:  # pycollada raises many types for a malformed file
        raise MeshError(f"{path}: pycollada cannot read it ({type(exc).__name__}: {exc})") from None
    unit = float(getattr(doc.assetInfo, "unitmeter", None) or 1.0)
    vertices, faces, count = [], [], 0
    scene = doc.scene if doc.scene is not None else (doc.scenes[0] if len(doc.scenes) else None)
    if scene is None:
        raise MeshError(f"{path}: the Collada file has no scene")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        bound = [prim for geometry in scene.objects("geometry") for prim in geometry.primitives()]
    colours: dict[tuple, int] = {}  # each material's diffuse colour, by the triangles it covers
    for prim in bound:
        if not isinstance(prim, (collada.triangleset.BoundTriangleSet, collada.polylist.BoundPolylist,
                                 collada.polygons.BoundPolygons)):  # fmt: skip
            continue  # lines and points draw nothing as a surface
        tris = prim if isinstance(prim, collada.triangleset.BoundTriangleSet) else prim.triangleset()
        if tris.vertex is None or not len(tris.vertex_index):
            continue
        vertices.append(np.asarray(tris.vertex, dtype=np.float64))
        faces.append(np.asarray(tris.vertex_index, dtype=np.int64).reshape(-1, 3) + count)
        count += len(vertices[-1])
        diffuse = getattr(getattr(getattr(prim, "material", None), "effect", None), "diffuse", None)
        if isinstance(diffuse, tuple) and len(diffuse) in (3, 4):  # a colour, not a texture map
            rgba = tuple(float(np.clip(c, 0.0, 1.0)) for c in (*diffuse[:3], diffuse[3] if len(diffuse) == 4 else 1))
            colours[rgba] = colours.get(rgba, 0) + len(faces[-1])
    if not faces:
        raise MeshError(f"{path}: the Collada scene has no triangles")
    rgba = max(colours, key=colours.get) if colours else None
    return Mesh(np.concatenate(vertices) * unit, np.concatenate(faces), rgba)
