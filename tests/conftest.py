import os

# Tests run on the CPU with a small fixed thread count so timings and compiles stay predictable.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault("XLA_FLAGS", "--xla_force_host_platform_device_count=1")
