"""Mesh export: canal_core's Mesh to PLY/OBJ/GLB through trimesh, or to JSON arrays."""

from __future__ import annotations

from typing import Literal

import numpy as np
import orjson
import trimesh

from canal_core import Mesh

MeshFormat = Literal["ply", "obj", "glb", "json"]

MESH_MEDIA_TYPES = {
    "ply": "application/octet-stream",
    "obj": "text/plain; charset=utf-8",
    "glb": "model/gltf-binary",
    "json": "application/json",
}


def export_mesh(mesh: Mesh, fmt: MeshFormat) -> bytes:
    """Encode ``mesh`` (vertices, faces, normals) in ``fmt``; pure function of its input."""
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    faces = np.asarray(mesh.faces, dtype=np.int64)
    normals = np.asarray(mesh.normals, dtype=np.float64)
    if fmt == "json":
        return orjson.dumps(
            {"vertices": vertices, "faces": faces, "normals": normals},
            option=orjson.OPT_SERIALIZE_NUMPY,
        )
    # process=False keeps canal_core's vertex order and normals exactly as computed.
    tri = trimesh.Trimesh(vertices=vertices, faces=faces, vertex_normals=normals, process=False)
    data = tri.export(file_type=fmt)
    return data.encode() if isinstance(data, str) else bytes(data)
