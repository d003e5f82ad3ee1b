"""Shared fixtures."""
import pytest
import torch


@pytest.fixture(scope="module")
def two_threads():
    """Pin torch to the appliance's 2 threads for a module whose numbers depend on the float
    summation order (use with pytestmark = pytest.mark.usefixtures("two_threads"))."""
    before = torch.get_num_threads()
    torch.set_num_threads(2)
    yield
    torch.set_num_threads(before)
