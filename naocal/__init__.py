"""naocal: automatic kinematic calibration for robots.

Installed, naocal is one import package: naocal.solver, naocal.agent, naocal.backends, naocal.body, naocal.sim,
naocal.tools. In a source checkout those folders stand beside this one (the repository's layout), so the package's
search path is widened to the checkout's root: `python -m naocal` and the tests run from the source as installed.
"""
from pathlib import Path as _Path

_here = _Path(__file__).resolve().parent
if not (_here / "solver").is_dir() and (_here.parent / "solver" / "__init__.py").is_file():
    __path__.append(str(_here.parent))  # noqa: F821 - the package's own search path
