import os

# Tests run on the CPU with a small fixed thread count so timings and compiles stay predictable.
# Most of the suite's time is XLA compiling small programs that then run briefly (backend compilation was
# 66 % of the in-process test time, measured with jax.monitoring). Without the fusion emitters and at LLVM
# opt level 0, compiles take about half as long; the programs run somewhat slower, and every test's
# tolerance holds. Library users keep XLA's defaults.
os.environ.setdefault("JAX_PLATFORMS", "cpu")
os.environ.setdefault(
    "XLA_FLAGS",
    "--xla_force_host_platform_device_count=1 --xla_backend_optimization_level=0 --xla_cpu_use_fusion_emitters=false",
)

import functools  # noqa: E402
import gc  # noqa: E402
import inspect  # noqa: E402

import jax  # noqa: E402
import jaxlie  # noqa: E402
import jaxtyping  # noqa: E402
import pytest  # noqa: E402

# Strict dtype promotion: mixing dtypes (float32 with float64, ints or bools with floats) raises instead of
# silently widening, so every cast in jaxquad is explicit. Passing strict means identical results under the
# default ("standard") promotion, which only adds implicit casts.
jax.config.update("jax_numpy_dtype_promotion", "strict")


def _standard_promotion(fn):
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        with jax.numpy_dtype_promotion("standard"):
            return fn(*args, **kwargs)

    return wrapped


def _exempt_from_strict_promotion():
    """jaxlie 1.5 (quaternion products and inverses multiply floats by int sign arrays), MJX (e.g.
    `1e-6 * (n == 0.0)` in its normalization) and optax's Adam (`b1 ** count`, count an int) rely on implicit
    promotion internally: their functions and methods run under standard promotion, jaxquad's own code under
    strict."""
    import optax
    from jaxlie import _base
    from mujoco import mjx
    from mujoco.mjx._src import support

    for cls in (_base.MatrixLieGroup, _base.SOBase, _base.SEBase, jaxlie.SO2, jaxlie.SO3, jaxlie.SE2, jaxlie.SE3):
        for name, attr in list(vars(cls).items()):
            if name.startswith("__") and name != "__matmul__":
                continue
            if isinstance(attr, classmethod | staticmethod):
                setattr(cls, name, type(attr)(_standard_promotion(attr.__func__)))
            elif callable(attr) and not inspect.isclass(attr):  # functions, and methods jaxlie jits
                setattr(cls, name, _standard_promotion(attr))
    for name in dir(mjx):
        attr = getattr(mjx, name)
        if not name.startswith("_") and inspect.isfunction(attr):
            setattr(mjx, name, _standard_promotion(attr))
    support.contact_force = _standard_promotion(support.contact_force)  # used by sim, not re-exported by mjx

    def adam(*args, **kwargs):
        tx = optax_adam(*args, **kwargs)
        return optax.GradientTransformation(_standard_promotion(tx.init), _standard_promotion(tx.update))

    optax_adam, optax.adam = optax.adam, adam


_exempt_from_strict_promotion()

# Every jaxtyping annotation in jaxquad (array types, dtypes, and named shapes consistent within one call) and
# every other annotation is checked at runtime by beartype, with `float` accepting `int` as static type checkers
# do (PEP 484's numeric tower). The hook must be installed before the first `import jaxquad`.
jaxtyping.install_import_hook(["jaxquad"], "beartype.beartype(conf=beartype.BeartypeConf(is_pep484_tower=True))")


@pytest.fixture(autouse=True, scope="module")
def _free_compiled_programs():
    """Drop each test module's compiled programs when it ends: the whole suite in one process
    otherwise holds every MJX executable at once, and the host runs out of memory in XLA."""
    yield
    jax.clear_caches()
    gc.collect()
