"""3DGS PLY round trip, the 3DGS property order, and errors that name the file and property."""
import numpy as np
import pytest

from recon.splat.ply import PlyError, read_gaussians_ply, write_gaussians_ply


def _gaussians(n=7, k=16, seed=0):
    rng = np.random.default_rng(seed)
    f = lambda *s: rng.normal(size=s).astype(np.float32)  # noqa: E731
    return dict(means=f(n, 3), quats=f(n, 4), log_scales=f(n, 3), opacity_logits=f(n), sh=f(n, k, 3))


@pytest.mark.parametrize("k", [1, 4, 9, 16])
def test_round_trip_with_extras(tmp_path, k):
    g = _gaussians(k=k)
    extra = {"thermal": np.arange(7, dtype=np.float32), "embedding": np.ones((7, 2), np.float32) * 3,
             "opacity_thermal": np.linspace(0, 1, 7).astype(np.float32)}
    write_gaussians_ply(tmp_path / "m.ply", **g, extra=extra)
    r = read_gaussians_ply(tmp_path / "m.ply")
    for key in g:
        np.testing.assert_array_equal(getattr(r, key), g[key])
    assert r.sh_degree == int(np.sqrt(k)) - 1
    assert set(r.extra) == set(extra)
    for key in extra:
        np.testing.assert_array_equal(r.extra[key], extra[key])


def _raw_3dgs_ply(path, n, k, values):
    """A PLY laid out exactly as 3DGS's save_ply, given property -> (N,) values."""
    names = ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    names += [f"f_rest_{i}" for i in range(3 * (k - 1))]
    names += ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {n}\n"
    header += "".join(f"property float {p}\n" for p in names) + "end_header\n"
    data = np.stack([values.get(p, np.zeros(n, np.float32)) for p in names], 1).astype("<f4")
    path.write_bytes(header.encode() + data.tobytes())
    return names


def test_reads_3dgs_channel_major_f_rest(tmp_path):
    n, k = 3, 9
    values = {f"f_rest_{i}": np.full(n, 100.0 + i, np.float32) for i in range(3 * (k - 1))}
    values["rot_0"] = np.full(n, 0.5, np.float32)
    values["rot_3"] = np.full(n, -0.5, np.float32)
    _raw_3dgs_ply(tmp_path / "a.ply", n, k, values)
    r = read_gaussians_ply(tmp_path / "a.ply")
    for c in range(3):
        for j in range(1, k):
            assert r.sh[0, j, c] == 100.0 + c * (k - 1) + (j - 1)
    np.testing.assert_array_equal(r.quats[0], [0.5, 0, 0, -0.5])  # rot_0..3 = w,x,y,z


def test_writer_uses_3dgs_layout(tmp_path):
    g = _gaussians(n=2, k=4)
    write_gaussians_ply(tmp_path / "m.ply", **g)
    raw = (tmp_path / "m.ply").read_bytes()
    header = raw[: raw.index(b"end_header")].decode().split("\n")
    props = [line.split()[2] for line in header if line.startswith("property")]
    assert props[:9] == ["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
    assert props[9:18] == [f"f_rest_{i}" for i in range(9)]
    assert props[18:] == ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    data = np.frombuffer(raw[raw.index(b"end_header\n") + 11:], "<f4").reshape(2, -1)
    assert data[1, 9 + 1 * 3 + 2] == g["sh"][1, 3, 1]  # f_rest index c*(K-1)+(k-1) with c=1, k=3


def test_missing_property_names_file_and_property(tmp_path):
    values = {}
    names = _raw_3dgs_ply(tmp_path / "ok.ply", 2, 1, values)
    raw = (tmp_path / "ok.ply").read_bytes().replace(b"property float scale_1\n", b"property float scalar\n")
    (tmp_path / "bad.ply").write_bytes(raw)
    assert "scale_1" in names
    with pytest.raises(PlyError, match=r"bad\.ply: missing property 'scale_1'"):
        read_gaussians_ply(tmp_path / "bad.ply")


@pytest.mark.parametrize("mutate,match", [
    (lambda raw: raw[:-5], r"truncated: 2 vertices need"),
    (lambda raw: b"PNG" + raw, r"not a PLY file"),
    (lambda raw: raw.replace(b"binary_little_endian", b"ascii"), r"format 'ascii' is not supported"),
    (lambda raw: raw.replace(b"property float opacity", b"property uchar opacity"), r"property 'opacity' must be float"),
    (lambda raw: raw.replace(b"property float rot_0", b"property quad rot_0"), r"property 'rot_0' has unknown type 'quad'"),
    (lambda raw: raw.replace(b"property float f_rest_8\n", b""), r"f_rest_\* properties must be"),
    (lambda raw: raw.replace(b"element vertex 2", b"element face 2"), r"element 'face' before 'vertex'"),
])
def test_malformed_ply_errors_name_the_file(tmp_path, mutate, match):
    _raw_3dgs_ply(tmp_path / "ok.ply", 2, 4, {})
    (tmp_path / "broken.ply").write_bytes(mutate((tmp_path / "ok.ply").read_bytes()))
    with pytest.raises(PlyError, match=r"broken\.ply: .*" + match):
        read_gaussians_ply(tmp_path / "broken.ply")


@pytest.mark.parametrize("prop,value", [("x", np.nan), ("scale_1", np.inf), ("f_rest_4", -np.inf)])
def test_non_finite_values_name_the_file_and_property(tmp_path, prop, value):
    values = {prop: np.array([0.0, value, 1.0], np.float32)}
    _raw_3dgs_ply(tmp_path / "nan.ply", 3, 4, values)
    with pytest.raises(PlyError, match=rf"nan\.ply: property '{prop}' has 1 non-finite values \(first at vertex 1\)"):
        read_gaussians_ply(tmp_path / "nan.ply")


def test_missing_file_names_it(tmp_path):
    with pytest.raises(PlyError, match=r"nope\.ply: cannot read"):
        read_gaussians_ply(tmp_path / "nope.ply")


def test_writer_rejects_bad_shapes_and_names(tmp_path):
    g = _gaussians()
    with pytest.raises(ValueError, match=r"quats must have shape \(N,4\)"):
        write_gaussians_ply(tmp_path / "m.ply", **dict(g, quats=np.zeros((7, 3))))
    with pytest.raises(ValueError, match=r"K=5"):
        write_gaussians_ply(tmp_path / "m.ply", **dict(g, sh=np.zeros((7, 5, 3))))
    with pytest.raises(ValueError, match=r"'opacity' is not a valid, unused"):
        write_gaussians_ply(tmp_path / "m.ply", **g, extra={"opacity": np.zeros(7)})
    with pytest.raises(ValueError, match=r"extra\['t'\] must have shape"):
        write_gaussians_ply(tmp_path / "m.ply", **g, extra={"t": np.zeros(6)})
