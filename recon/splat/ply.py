"""Read and write Gaussians in the standard 3DGS PLY layout, plus named extra properties.

Layout (binary little-endian, one `vertex` element, float32 properties in this order):
x y z, nx ny nz, f_dc_0..2, f_rest_0..f_rest_{3(K-1)-1} (channel-major: f_rest index =
c*(K-1) + (k-1) for SH coefficient k >= 1 of channel c), opacity (logit), scale_0..2 (log),
rot_0..3 (quaternion wxyz), then the extras: an (N,) array `name` is one property `name`, an
(N,k) array is `name_0..name_{k-1}`. The reader groups `name_<j>` properties back into (N,k).
"""
from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
_BASE = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
_TAIL = ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
_REST = re.compile(r"^f_rest_(\d+)$")
_GROUPED = re.compile(r"^(.*)_(\d+)$")


class PlyError(ValueError):
    """A malformed or unsupported PLY; the message names the file and the property."""


@dataclass
class GaussianPly:
    means: np.ndarray           # (N,3) float32
    quats: np.ndarray           # (N,4) wxyz, as stored (not normalised)
    log_scales: np.ndarray      # (N,3)
    opacity_logits: np.ndarray  # (N,)
    sh: np.ndarray              # (N,K,3) SH coefficients, K = (degree+1)^2
    normals: np.ndarray         # (N,3) (3DGS writes zeros)
    extra: dict[str, np.ndarray] = field(default_factory=dict)  # (N,) or (N,k) float32

    @property
    def sh_degree(self) -> int:
        return int(round(np.sqrt(self.sh.shape[1]))) - 1


def _array(name: str, value, n: int | None, shape_tail: tuple) -> np.ndarray:
    if hasattr(value, "detach"):  # torch tensor
        value = value.detach().cpu().numpy()
    a = np.asarray(value, dtype=np.float32)
    if a.ndim != 1 + len(shape_tail) or (n is not None and a.shape[0] != n) or any(
        t != -1 and s != t for s, t in zip(a.shape[1:], shape_tail)
    ):
        want = "(" + ",".join(["N"] + ["k" if t == -1 else str(t) for t in shape_tail]) + ")"
        raise ValueError(f"{name} must have shape {want} with N={n}, got {a.shape}")
    return a


def write_gaussians_ply(path, means, quats, log_scales, opacity_logits, sh, extra=None, normals=None) -> None:
    """Write a 3DGS PLY. sh: (N,K,3) with K a square; extra: {name: (N,) or (N,k)} floats."""
    means = _array("means", means, None, (3,))
    n = means.shape[0]
    quats = _array("quats", quats, n, (4,))
    log_scales = _array("log_scales", log_scales, n, (3,))
    opacity_logits = _array("opacity_logits", opacity_logits, n, ())
    sh = _array("sh", sh, n, (-1, 3))
    k = sh.shape[1]
    if k < 1 or int(round(np.sqrt(k))) ** 2 != k:
        raise ValueError(f"sh must have (degree+1)^2 coefficients per channel, got K={k}")
    normals = np.zeros((n, 3), np.float32) if normals is None else _array("normals", normals, n, (3,))
    rest = sh[:, 1:, :].transpose(0, 2, 1).reshape(n, -1)  # channel-major, as 3DGS
    columns = [means, normals, sh[:, 0, :], rest, opacity_logits[:, None], log_scales, quats]
    names = _BASE[:6] + _BASE[6:] + [f"f_rest_{i}" for i in range(rest.shape[1])] + _TAIL
    for key, value in (extra or {}).items():
        if not _NAME.match(key) or key in names or _REST.match(key):
            raise ValueError(f"extra property name {key!r} is not a valid, unused PLY property name")
        a = np.asarray(value.detach().cpu().numpy() if hasattr(value, "detach") else value, np.float32)
        if a.ndim not in (1, 2) or a.shape[0] != n:
            raise ValueError(f"extra[{key!r}] must have shape (N,) or (N,k) with N={n}, got {a.shape}")
        if a.ndim == 1:
            columns.append(a[:, None])
            names.append(key)
        else:
            columns.append(a)
            names += [f"{key}_{j}" for j in range(a.shape[1])]
    if len(set(names)) != len(names):
        raise ValueError("extra property names collide with each other after expansion to name_<j>")
    data = np.ascontiguousarray(np.concatenate(columns, axis=1), dtype="<f4")
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {n}"]
    header += [f"property float {name}" for name in names] + ["end_header"]
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())


def _parse_header(path: Path, raw: bytes) -> tuple[str, int, list[tuple[str, str]], int]:
    """-> (format, vertex count, [(property, numpy type)], offset of the vertex data)."""
    end = raw.find(b"end_header")
    if not raw.startswith(b"ply") or end < 0:
        raise PlyError(f"{path}: not a PLY file (no 'ply' magic or no 'end_header')")
    nl = raw.find(b"\n", end)
    offset = len(raw) if nl < 0 else nl + 1
    lines = raw[:end].decode("ascii", errors="replace").splitlines()
    fmt, count, props, element = None, None, [], None
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            fmt = words[1] if len(words) > 1 else ""
        elif words[0] == "element":
            if element == "vertex":
                break  # vertex data comes first: later elements (faces, ...) are not needed
            if len(words) != 3 or not words[2].isdigit():
                raise PlyError(f"{path}: bad element line {line!r}")
            element = words[1]
            if element != "vertex":
                raise PlyError(f"{path}: element {element!r} before 'vertex' is not supported")
            count = int(words[2])
        elif words[0] == "property" and element == "vertex":
            if len(words) != 3 or words[1] == "list":
                raise PlyError(f"{path}: unsupported vertex property line {line!r}")
            if words[1] not in _PLY_TYPES:
                raise PlyError(f"{path}: property {words[2]!r} has unknown type {words[1]!r}")
            props.append((words[2], _PLY_TYPES[words[1]]))
    if fmt not in ("binary_little_endian", "binary_big_endian"):
        raise PlyError(f"{path}: format {fmt!r} is not supported (3DGS PLYs are binary_little_endian)")
    if count is None:
        raise PlyError(f"{path}: no 'element vertex' in the header")
    return fmt, count, props, offset


def read_gaussians_ply(path) -> GaussianPly:
    """Read a 3DGS PLY written by 3DGS, gsplat, nerfstudio or write_gaussians_ply."""
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as e:
        raise PlyError(f"{path}: cannot read: {e.strerror or e}") from e
    fmt, n, props, offset = _parse_header(path, raw)
    endian = "<" if fmt == "binary_little_endian" else ">"
    names = [p for p, _ in props]
    if len(set(names)) != len(names):
        raise PlyError(f"{path}: duplicate property names in 'vertex'")
    dtype = np.dtype([(p, endian + t) for p, t in props])
    need = n * dtype.itemsize
    if len(raw) - offset < need:
        raise PlyError(f"{path}: truncated: {n} vertices need {need} bytes of data, file has {len(raw) - offset}")
    table = np.frombuffer(raw, dtype=dtype, count=n, offset=offset)

    def column(name: str) -> np.ndarray:
        if name not in table.dtype.names:
            raise PlyError(f"{path}: missing property {name!r} in element 'vertex'")
        if table.dtype[name].kind != "f":
            raise PlyError(f"{path}: property {name!r} must be float, got {table.dtype[name]}")
        values = table[name].astype(np.float32)
        bad = ~np.isfinite(values)
        if bad.any():
            raise PlyError(f"{path}: property {name!r} has {int(bad.sum())} non-finite values "
                           f"(first at vertex {int(bad.argmax())})")
        return values

    def stack(cols: list[str]) -> np.ndarray:
        return np.stack([column(c) for c in cols], 1) if cols else np.zeros((n, 0), np.float32)

    rest_ids = sorted(int(m.group(1)) for p in names if (m := _REST.match(p)))
    if rest_ids != list(range(len(rest_ids))) or len(rest_ids) % 3:
        raise PlyError(f"{path}: f_rest_* properties must be f_rest_0..f_rest_(3m-1), got {len(rest_ids)}")
    k = len(rest_ids) // 3 + 1
    if int(round(np.sqrt(k))) ** 2 != k:
        raise PlyError(f"{path}: {len(rest_ids)} f_rest_* properties do not make a full SH degree")
    rest = stack([f"f_rest_{i}" for i in rest_ids]).reshape(n, 3, k - 1).transpose(0, 2, 1)
    sh = np.concatenate([stack(_BASE[6:9])[:, None, :], rest], 1)
    normals = stack(_BASE[3:6]) if all(c in names for c in _BASE[3:6]) else np.zeros((n, 3), np.float32)
    known = set(_BASE) | set(_TAIL) | {f"f_rest_{i}" for i in rest_ids}
    extra: dict[str, np.ndarray] = {}
    grouped: dict[str, list[tuple[int, str]]] = {}
    for p in names:
        if p in known:
            continue
        m = _GROUPED.match(p)
        if m:
            grouped.setdefault(m.group(1), []).append((int(m.group(2)), p))
        else:
            extra[p] = table[p].astype(np.float32)
    for base, items in grouped.items():
        items.sort()
        if base in extra or [j for j, _ in items] != list(range(len(items))):
            for _, p in items:  # not a clean name_0..name_{k-1} group: keep them separate
                extra[p] = table[p].astype(np.float32)
        else:
            extra[base] = np.stack([table[p].astype(np.float32) for _, p in items], 1)
    return GaussianPly(
        means=stack(_BASE[:3]), quats=stack(_TAIL[4:8]), log_scales=stack(_TAIL[1:4]),
        opacity_logits=column("opacity"), sh=sh, normals=normals, extra=extra,
    )
