import pytest
import torch

from dem.case import CollapseCase


@pytest.fixture
def small_case():
    """A coarse-grained quartz column (~270 grains) that collapses in about two seconds."""
    return CollapseCase(
        "quartz",
        L_i=0.02,
        aspect_ratio=1.0,
        friction=0.5,
        restitution=0.65,
        size_scale=3.0,
        seed=3,
        name="small",
    )


@pytest.fixture(scope="module")
def one_torch_thread():
    """Tiny graphs: one torch thread is faster than two and does not spin against other jobs."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
