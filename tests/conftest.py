import os

# Tests run on the CPU with a small fixed thread count so timings and compiles stay predictable.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")

import gc  # noqa: E402

import pytest  # noqa: E402


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop each test module's compiled programs when it ends: the whole suite in one process
    otherwise holds every MJX executable at once, and the host runs out of memory in XLA."""
    yield
    import jax

    jax.clear_caches()
    gc.collect()
