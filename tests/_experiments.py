"""The scripts of experiments/ as modules, for tests of their functions."""

from __future__ import annotations

import importlib.util
from pathlib import Path
from types import ModuleType

EXPERIMENTS = Path(__file__).resolve().parents[1] / "experiments"


def load(script: str, module_name: str | None = None) -> ModuleType:
    """experiments/<script>.py executed as a module named `module_name` (default: the script's name)."""
    spec = importlib.util.spec_from_file_location(module_name or script, EXPERIMENTS / f"{script}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module
