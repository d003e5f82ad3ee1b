"""recon/dtg/neighbours.py: exact k nearest neighbours (KD-tree) against brute force in float64."""
import torch

from recon.dtg.neighbours import knn_indices, knn_mean_sq_dist


def brute(points: torch.Tensor, k: int):
    d2 = torch.cdist(points.double(), points.double()).pow(2)
    d2.fill_diagonal_(float("inf"))
    vals, idx = d2.topk(k, largest=False)
    return vals, idx


def test_neighbours_equal_brute_force_and_never_include_the_point_itself():
    gen = torch.Generator().manual_seed(0)
    pts = torch.rand(700, 3, generator=gen) * torch.tensor([4.0, 1.0, 0.2])   # anisotropic cloud
    pts[5] = pts[6]                       # an exact duplicate: its twin is at distance 0
    idx = knn_indices(pts, 8)
    vals, ref = brute(pts, 8)
    assert idx.shape == (700, 8) and idx.dtype == torch.long
    assert not (idx == torch.arange(700)[:, None]).any()
    # the same neighbours up to ties (the duplicate ties for everyone else): the same distances
    got = (pts.double()[idx] - pts.double()[:, None]).pow(2).sum(-1)
    assert torch.allclose(got.sort(1).values, vals, rtol=1e-9, atol=1e-15)
    assert int(idx[5, 0]) == 6 and int(idx[6, 0]) == 5
    unique = torch.cat([pts[:5], pts[7:]])      # without ties: the same indices
    assert torch.equal(knn_indices(unique, 8).sort(1).values, brute(unique, 8)[1].sort(1).values)
    d = knn_mean_sq_dist(pts, k=3)
    assert torch.allclose(d.double(), vals[:, :3].mean(1), rtol=1e-5, atol=1e-12)


def test_fewer_points_than_neighbours():
    pts = torch.tensor([[0.0, 0, 0], [1.0, 0, 0], [0.0, 2, 0]])
    assert knn_indices(pts, 8).tolist() == [[1, 2], [0, 2], [0, 1]]
    assert knn_mean_sq_dist(pts, k=8).tolist() == [2.5, 3.0, 4.5]
    assert knn_indices(pts[:1], 8).shape == (1, 0)
    assert knn_mean_sq_dist(pts[:1]).tolist() == [1.0]
