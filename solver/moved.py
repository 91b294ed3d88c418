"""Old module names that still import for one release after their module moved (issue 13's boundaries).

`alias_moved_modules({"old.name": "new.name"})` makes `import old.name` (and `from old.name import x`) give the
module `new.name` itself, so old imports keep working without a second file at the old path (which would hide the
move from git's rename detection when branches that edit the old file are merged).
"""

import importlib
import importlib.abc
import importlib.util
import sys


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def __init__(self, moved: dict):
        self.moved = dict(moved)

    def find_spec(self, fullname, path=None, target=None):
        return importlib.util.spec_from_loader(fullname, self) if fullname in self.moved else None

    def create_module(self, spec):
        return importlib.import_module(self.moved[spec.name])

    def exec_module(self, module):
        pass


def alias_moved_modules(moved: dict) -> None:
    """Register old -> new module names (imported lazily, on first use of the old name)."""
    sys.meta_path.append(_MovedModules(moved))
