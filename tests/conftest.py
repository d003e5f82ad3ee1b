"""Shared fixtures."""
import os

import pytest
import torch

# Training in tests (and in the processes they start) keeps its thread count whatever else runs:
# torch's float sums depend on it, and tests compare numbers (recon/train/cores.py).
os.environ["RECON_FIXED_THREADS"] = "1"


@pytest.fixture(scope="module")
def two_threads():
    """Pin torch to the appliance's 2 threads for a module whose numbers depend on the float
    summation order (use with pytestmark = pytest.mark.usefixtures("two_threads"))."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)
