import pytest

from dem.case import CollapseCase


@pytest.fixture
def small_case():
    """A coarse-grained quartz column (~270 grains) that collapses in about two seconds."""
    return CollapseCase("quartz", column_length=0.02, aspect_ratio=1.0, friction=0.5, restitution=0.65,
                        size_scale=3.0, seed=3, name="small")
