import os

import pytest
from hypothesis import settings

# Property tests draw the same examples on every run and every machine (no example database, no
# random seed), so a rare example cannot fail one run in fifty: a failure is reproducible.
settings.register_profile('deterministic', derandomize=True, database=None)
settings.load_profile('deterministic')

# DDS traffic of the tests stays on this machine, in a domain of its own.
os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
os.environ.setdefault('ROS_DOMAIN_ID', '87')


def pytest_configure(config):
    config.addinivalue_line('markers', 'slow: takes more than a few seconds')
    config.addinivalue_line('markers', 'ros: needs rclpy')


@pytest.fixture
def rng():
    import numpy as np
    return np.random.default_rng(12345)


@pytest.fixture(scope='session')
def model_file(tmp_path_factory):
    """One model file of the right architecture (seeded, untrained) for the pipeline tests."""
    from test_assessor import make_model
    return make_model(tmp_path_factory.mktemp('model') / 'small.safetensors')
