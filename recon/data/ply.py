"""Initial sparse points as PLY: one `vertex` element with x, y, z and red, green, blue.

Reads ASCII and binary (little or big endian) files whose vertex element has at least those
six properties (others, e.g. normals, are ignored); writes binary little endian with float32
positions and uchar colours, the layout COLMAP and nerfstudio export.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from recon.data.errors import DatasetError

PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4",
             "uint32": "u4", "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
REQUIRED = ("x", "y", "z", "red", "green", "blue")


def _parse_header(path: Path, data: bytes) -> tuple[str, list[tuple[str, int, list]], int]:
    """(format, [(element, count, [(property, dtype)])], byte offset of the body)."""
    end = data.find(b"end_header\n")
    if not data.startswith(b"ply") or end < 0:
        raise DatasetError(f"{path}: not a PLY file (no 'ply' magic or no end_header)")
    fmt, elements = None, []
    for line in data[:end].decode("ascii", "replace").splitlines()[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1]
        elif words[0] == "element":
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list":
                raise DatasetError(f"{path}: list properties (faces) are not supported; points only")
            if words[1] not in PLY_TYPES:
                raise DatasetError(f"{path}: unknown PLY property type {words[1]!r}")
            elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
    if fmt not in ("ascii", "binary_little_endian", "binary_big_endian"):
        raise DatasetError(f"{path}: unsupported PLY format {fmt!r}")
    return fmt, elements, end + len(b"end_header\n")


def read_points_ply(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """xyz (M, 3) float64 and rgb (M, 3) uint8 from the file's vertex element."""
    data = path.read_bytes()
    fmt, elements, body = _parse_header(path, data)
    if not elements or elements[0][0] != "vertex":
        raise DatasetError(f"{path}: the first PLY element must be 'vertex'")
    _, count, props = elements[0]
    missing = [p for p in REQUIRED if p not in dict(props)]
    if missing:
        raise DatasetError(f"{path}: vertex element lacks {', '.join(missing)}")
    if fmt == "ascii":
        rows = data[body:].decode("ascii").split("\n")[:count]
        try:
            table = np.array([r.split()[: len(props)] for r in rows], dtype=np.float64)
        except ValueError:
            raise DatasetError(f"{path}: malformed ASCII vertex rows") from None
        if table.shape != (count, len(props)):
            raise DatasetError(f"{path}: expected {count} vertex rows of {len(props)} values")
        columns = {name: table[:, i] for i, (name, _) in enumerate(props)}
    else:
        order = "<" if fmt == "binary_little_endian" else ">"
        dtype = np.dtype([(name, order + t) for name, t in props])
        if len(data) - body < count * dtype.itemsize:
            raise DatasetError(f"{path}: file is truncated ({count} vertices declared)")
        columns = np.frombuffer(data, dtype=dtype, count=count, offset=body)
    xyz = np.stack([columns[c] for c in "xyz"], axis=1).astype(np.float64)
    rgb = np.stack([columns[c] for c in ("red", "green", "blue")], axis=1)
    if not np.isfinite(xyz).all():
        raise DatasetError(f"{path}: non-finite point coordinates")
    return xyz, np.clip(rgb, 0, 255).astype(np.uint8)


def write_points_ply(path: Path, xyz: np.ndarray, rgb: np.ndarray) -> None:
    """Write xyz (M, 3) and rgb (M, 3) uint8 as binary little-endian PLY."""
    xyz, rgb = np.asarray(xyz), np.asarray(rgb)
    if xyz.ndim != 2 or xyz.shape[1] != 3 or rgb.shape != xyz.shape:
        raise ValueError(f"points must be (M, 3) with colours (M, 3), got {xyz.shape} and {rgb.shape}")
    vertex = np.empty(len(xyz), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                       ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for i, c in enumerate("xyz"):
        vertex[c] = xyz[:, i]
    for i, c in enumerate(("red", "green", "blue")):
        vertex[c] = rgb[:, i]
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"element vertex {len(xyz)}\n"
              "property float x\nproperty float y\nproperty float z\n"
              "property uchar red\nproperty uchar green\nproperty uchar blue\nend_header\n")
    path.write_bytes(header.encode("ascii") + vertex.tobytes())
