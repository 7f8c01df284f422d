"""jaxquad: state estimation, mapping and navigation for low-cost quadruped robots, in JAX."""

from pathlib import Path as _Path

# In a source checkout kernels/ and sim/ sit beside jaxquad/; the installed package maps them to
# jaxquad.kernels and jaxquad.sim. Extending __path__ makes both layouts import the same way.
_root = _Path(__file__).resolve().parent.parent
if (_root / "kernels" / "__init__.py").is_file() and str(_root) not in __path__:
    __path__.append(str(_root))

__version__ = "0.1.0"
