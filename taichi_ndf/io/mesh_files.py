"""Triangle meshes to and from OBJ and PLY files, vertex order preserved."""

import io
import os
from dataclasses import dataclass, field

import numpy as np

from taichi_ndf.io.output_dir import atomic_path

__all__ = ["MeshData", "write_obj", "write_ply", "read_mesh"]

# PLY vertex properties that are geometry or appearance rather than per-vertex scalars.
_PLY_STANDARD_PROPERTIES = frozenset(
    "x y z nx ny nz s t u v texture_u texture_v red green blue alpha".split()
)


@dataclass(frozen=True)
class MeshData:
    """A triangle mesh as read from a file.

    vertices: positions, shape (V, 3), in file order; faces: triangles, shape (F, 3), int64;
    uvs: per-vertex texture coordinates (V, 2) or None; vertex_scalars: extra per-vertex PLY
    properties by name, each shape (V,).
    """

    vertices: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray | None = None
    vertex_scalars: dict[str, np.ndarray] = field(default_factory=dict)


def _check_mesh(vertices, faces, uvs=None, normals=None):
    vertices = np.asarray(vertices, dtype=np.float64)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise ValueError(f"vertices must have shape (V, 3), got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or not np.issubdtype(faces.dtype, np.integer):
        raise ValueError(f"faces must be integers of shape (F, 3), got {faces.dtype} {faces.shape}")
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError(f"faces index vertices outside [0, {len(vertices)})")
    for name, array, width in (("uvs", uvs, 2), ("normals", normals, 3)):
        if array is not None and np.shape(array) != (len(vertices), width):
            raise ValueError(
                f"{name} must have shape ({len(vertices)}, {width}), got {np.shape(array)}"
            )
    if not np.all(np.isfinite(vertices)):
        raise ValueError("vertices contain NaN or infinity")
    return vertices, faces.astype(np.int64)


def _rows(array: np.ndarray, prefix: str) -> str:
    buffer = io.StringIO()
    np.savetxt(buffer, array, fmt="%.9g", delimiter=" ")
    return "".join(f"{prefix} {line}\n" for line in buffer.getvalue().splitlines())


def write_obj(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    uvs: np.ndarray | None = None,
    normals: np.ndarray | None = None,
    objects: list[tuple[str, int]] | None = None,
) -> None:
    """Write a Wavefront OBJ (atomically).

    vertices: positions, shape (V, 3); faces: triangles, shape (F, 3), 0-based;
    uvs: per-vertex texture coordinates (V, 2), OBJ convention (v up); normals: (V, 3).
    Vertex i of the arrays is vertex i + 1 of the file; texture and normal indices equal the
    vertex index, so readers keep the vertex order.
    objects: (name, vertex count) of consecutive runs of vertices, each an object (`o name`
    followed by its vertices and the faces among them, e.g. a garment's panels; a face
    across two objects: ValueError); None: one nameless object.
    """
    vertices, faces = _check_mesh(vertices, faces, uvs, normals)
    if objects is not None:
        ends = np.cumsum([count for _, count in objects])
        if not len(ends) or ends[-1] != len(vertices):
            raise ValueError(f"objects: {ends[-1] if len(ends) else 0} vertices named, the "
                             f"mesh has {len(vertices)}")
        owner = np.searchsorted(ends, faces, side="right")
        if (owner != owner[:, :1]).any() or (np.diff(owner[:, 0]) < 0).any():
            raise ValueError("objects: a face joins two objects, or faces are not in their "
                             "objects' order")
        starts, face_ends = np.concatenate(([0], ends)), np.searchsorted(owner[:, 0],
                                                                          np.arange(len(ends)),
                                                                          side="right")
        face_starts = np.concatenate(([0], face_ends[:-1]))
        text = "".join(f"o {name}\n" + _obj_body(vertices[a:b], faces[c:d],
                                                 None if uvs is None else uvs[a:b],
                                                 None if normals is None else normals[a:b])
                       for (name, _), a, b, c, d in zip(objects, starts, ends, face_starts,
                                                        face_ends, strict=False))
    else:
        text = _obj_body(vertices, faces, uvs, normals)
    with atomic_path(path) as temporary:
        temporary.write_text(text, encoding="ascii")


def _obj_body(vertices: np.ndarray, faces: np.ndarray, uvs, normals) -> str:
    """OBJ lines of vertices (their texture coordinates and normals) and faces (0-based
    indices into all the file's vertices, these and those before)."""
    parts = [_rows(vertices, "v")]
    if uvs is not None:
        parts.append(_rows(np.asarray(uvs, dtype=np.float64), "vt"))
    if normals is not None:
        parts.append(_rows(np.asarray(normals, dtype=np.float64), "vn"))
    one_based = faces + 1
    if uvs is not None and normals is not None:
        corner, fmt = np.repeat(one_based, 3, axis=1), "%d/%d/%d"
    elif uvs is not None:
        corner, fmt = np.repeat(one_based, 2, axis=1), "%d/%d"
    elif normals is not None:
        corner, fmt = np.repeat(one_based, 2, axis=1), "%d//%d"
    else:
        corner, fmt = one_based, "%d"
    buffer = io.StringIO()
    np.savetxt(buffer, corner, fmt=" ".join([fmt] * 3))
    parts.append("".join(f"f {line}\n" for line in buffer.getvalue().splitlines()))
    return "".join(parts)


def write_ply(
    path: str | os.PathLike,
    vertices: np.ndarray,
    faces: np.ndarray,
    *,
    uvs: np.ndarray | None = None,
    vertex_scalars: dict[str, np.ndarray] | None = None,
    binary: bool = True,
    comments: list[str] | None = None,
) -> None:
    """Write a PLY file (atomically), binary little-endian or ASCII.

    vertices: positions, shape (V, 3), stored as float32; faces: triangles, shape (F, 3);
    uvs: per-vertex texture coordinates (V, 2), stored as properties ``s``, ``t``;
    vertex_scalars: extra per-vertex float32 properties, e.g. ``{"membrane_strain": (V,),
    "energy_density": (V,)}``; names must be identifiers and not clash with standard ones.
    comments: further header comments, one line each (e.g. what a property's values name).
    """
    vertices, faces = _check_mesh(vertices, faces, uvs)
    if any("\n" in c or "\r" in c for c in comments or ()):
        raise ValueError("a PLY comment is one line")
    columns = {"x": vertices[:, 0], "y": vertices[:, 1], "z": vertices[:, 2]}
    if uvs is not None:
        uvs = np.asarray(uvs, dtype=np.float64)
        columns["s"], columns["t"] = uvs[:, 0], uvs[:, 1]
    for name, values in (vertex_scalars or {}).items():
        if not name.isidentifier() or name in _PLY_STANDARD_PROPERTIES:
            raise ValueError(f"vertex scalar name {name!r} is not a usable PLY property name")
        values = np.asarray(values, dtype=np.float64)
        if values.shape != (len(vertices),):
            raise ValueError(
                f"vertex scalar {name!r} must have shape ({len(vertices)},), got {values.shape}"
            )
        columns[name] = values

    header = [
        "ply",
        f"format {'binary_little_endian' if binary else 'ascii'} 1.0",
        "comment written by taichi_ndf",
        *(f"comment {c}" for c in comments or ()),
        f"element vertex {len(vertices)}",
    ]
    header += [f"property float {name}" for name in columns]
    header += [f"element face {len(faces)}", "property list uchar int vertex_indices", "end_header"]
    vertex_table = np.stack(list(columns.values()), axis=1).astype("<f4")
    if binary:
        face_table = np.empty(len(faces), dtype=[("n", "u1"), ("corners", "<i4", (3,))])
        face_table["n"], face_table["corners"] = 3, faces
        body = vertex_table.tobytes() + face_table.tobytes()
    else:
        text = io.StringIO()
        np.savetxt(text, vertex_table, fmt="%.9g")
        np.savetxt(text, np.column_stack([np.full(len(faces), 3), faces]), fmt="%d")
        body = text.getvalue().encode("ascii")
    with atomic_path(path) as temporary:
        temporary.write_bytes(("\n".join(header) + "\n").encode("ascii") + body)


def read_mesh(path: str | os.PathLike) -> MeshData:
    """Read an OBJ or PLY triangle mesh with trimesh, keeping the file's vertex order.

    UVs come from OBJ ``vt`` or PLY ``s``/``t`` (also ``u``/``v``, ``texture_u``/``texture_v``);
    other per-vertex PLY properties are returned in ``vertex_scalars``. A file that gives one
    vertex several UVs (per-corner seams) is read with ``uvs=None``: splitting its vertices would
    change the vertex order.
    """
    import trimesh

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise FileNotFoundError(f"mesh file not found: {path}")
    # load_scene, not load_mesh: load_mesh copies the geometry, which needs Pillow for textured
    # materials, and concatenates parts (dropping the PLY metadata read below).
    try:
        scene = trimesh.load_scene(path, process=False, maintain_order=True, fix_texture=False)
    except Exception as err:  # trimesh raises many kinds (decode, import, index) on bad files
        reason = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        raise ValueError(f"{path}: not a readable OBJ or PLY mesh ({reason[:200]})") from None
    meshes = list(scene.geometry.values())
    if len(meshes) != 1 or not isinstance(meshes[0], trimesh.Trimesh):
        raise ValueError(f"{path} does not hold exactly one triangle mesh")
    mesh = meshes[0]
    uv = getattr(mesh.visual, "uv", None)
    if uv is None and path.lower().endswith(".obj"):
        uv = _obj_vertex_uvs(path, len(mesh.vertices))
    scalars = {}
    vertex_element = mesh.metadata.get("_ply_raw", {}).get("vertex", {}).get("data")
    if vertex_element is not None:
        names = (
            vertex_element.keys()
            if isinstance(vertex_element, dict)
            else (vertex_element.dtype.names)
        )
        scalars = {
            name: np.asarray(vertex_element[name], dtype=np.float64).ravel()
            for name in names
            if name not in _PLY_STANDARD_PROPERTIES
        }
    return MeshData(
        vertices=np.asarray(mesh.vertices, dtype=np.float64),
        faces=np.asarray(mesh.faces, dtype=np.int64),
        uvs=None if uv is None else np.asarray(uv, dtype=np.float64),
        vertex_scalars=scalars,
    )


def _obj_vertex_uvs(path: str, vertex_count: int) -> np.ndarray | None:
    """Per-vertex UVs (V, 2) of an OBJ file from its ``vt`` lines and face corners ``v/vt``, or
    None when it has none or gives a vertex several UVs. trimesh drops the UVs of polygons
    (quads) that it triangulates; the vertex order it keeps is the file's."""
    try:
        return _read_obj_vertex_uvs(path, vertex_count)
    except (ValueError, IndexError):  # malformed numbers or indices: no usable UVs
        return None


def _read_obj_vertex_uvs(path: str, vertex_count: int) -> np.ndarray | None:
    texture, vertex_uv = [], {}
    with open(path, encoding="utf-8", errors="replace") as stream:
        for line in stream:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "vt" and len(parts) >= 3:
                texture.append((float(parts[1]), float(parts[2])))
            elif parts[0] == "f":
                for corner in parts[1:]:
                    indices = corner.split("/")
                    if len(indices) < 2 or not indices[1]:
                        return None
                    v, t = int(indices[0]), int(indices[1])
                    v = v - 1 if v > 0 else vertex_count + v
                    t = t - 1 if t > 0 else len(texture) + t
                    if vertex_uv.setdefault(v, t) != t:
                        return None  # a seam: several UVs at one vertex
    if not texture or len(vertex_uv) != vertex_count or set(vertex_uv) != set(range(vertex_count)):
        return None
    return np.array([texture[vertex_uv[v]] for v in range(vertex_count)], dtype=np.float64)
