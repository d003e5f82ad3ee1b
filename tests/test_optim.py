"""The run's optimizer (recon/train/optim.py LeanAdam): torch's fused Adam without its per-step
bookkeeping must give the same parameters and state, bit for bit."""
import torch

from recon.train.optim import LeanAdam


def params():
    gen = torch.Generator().manual_seed(1)
    return [torch.nn.Parameter(torch.randn(100, 3, generator=gen)) for _ in range(4)] + \
        [torch.nn.Parameter(torch.randn(7, generator=gen))]


def groups(ps):
    # two groups share a rate (one kernel call in LeanAdam), one has two tensors
    return [{"params": [ps[0]], "lr": 0.1}, {"params": [ps[1]], "lr": 0.01},
            {"params": [ps[2], ps[3]], "lr": 0.1}, {"params": [ps[4]], "lr": 0.5}]


def test_lean_adam_equals_torch_fused_adam():
    a, b = params(), params()
    torch_adam = torch.optim.Adam(groups(a), lr=0.0, eps=1e-15, fused=True)
    lean = LeanAdam(groups(b), lr=0.0, eps=1e-15, fused=True)
    for it in range(10):
        gen = torch.Generator().manual_seed(100 + it)
        grads = [torch.randn(p.shape, generator=gen) for p in a]
        for ps, opt in ((a, torch_adam), (b, lean)):
            opt.zero_grad(set_to_none=True)
            for i, (p, g) in enumerate(zip(ps, grads)):
                if not (it % 3 == 1 and i == 2):        # a tensor without a gradient is not stepped
                    p.grad = g.clone()
            if it == 5:
                opt.param_groups[1]["lr"] = 0.2         # rates change between steps
            opt.step()
    for x, y in zip(a, b):
        assert torch.equal(x, y)
        for key in ("exp_avg", "exp_avg_sq", "step"):
            assert torch.equal(torch_adam.state[x][key], lean.state[y][key])
    resumed = LeanAdam(groups(params()), lr=0.0, eps=1e-15, fused=True)
    resumed.load_state_dict(lean.state_dict())
    assert all(torch.equal(s["exp_avg"], lean.state[p]["exp_avg"])
               for s, p in zip(resumed.state.values(), b))
