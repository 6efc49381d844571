"""Twin runs shared by the identification tests (made once per session, in a temporary directory)."""

import pytest

from experiments.compress import run_compress
from experiments.free_motion import run_free_motion
from twin.sim.backend import SimBackend
from twin.sim.foam import get_object

SPHERE_YOUNG_PA = 57_300.0
"""Off the mapping's grid (nearest grid moduli 49.4 and 58.3 kPa): a modulus it has not seen."""


@pytest.fixture(scope="session")
def sphere_run(tmp_path_factory):
    """14 s compress of the library sphere at an unseen modulus, sensor noise on, an unused noise seed."""
    foam = get_object("sphere").with_overrides(young_pa=SPHERE_YOUNG_PA)
    path = tmp_path_factory.mktemp("identify") / "sphere"
    run_compress(SimBackend(foam, seed=42), path, duration_s=14.0, object_name=foam.name)
    return path


@pytest.fixture(scope="session")
def free_run(tmp_path_factory):
    """10 s of the empty hand swinging its fingers."""
    path = tmp_path_factory.mktemp("identify") / "free"
    run_free_motion(SimBackend(None, seed=3), path, duration_s=10.0)
    return path


@pytest.fixture(scope="session")
def no_tactile_run(tmp_path_factory):
    """A short compress run of a twin without pads."""
    path = tmp_path_factory.mktemp("identify") / "no-tactile"
    run_compress(SimBackend(get_object("sphere"), tactile=False), path, duration_s=4.0, object_name="sphere")
    return path
