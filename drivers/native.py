"""mypyc's class options for the compiled build (setup.py), and a no-op where mypy_extensions is missing.

`@mypyc_attr(allow_interpreted_subclasses=True)` on a class of a compiled module lets Python classes derive
from it (a device profile's `ProfileNode` from `CanNode`, a test's or a benchmark's `Rig`): a compiled class
is otherwise closed, to subclasses as to patches. mypyc reads the decorator when it compiles; at run time it
does nothing, and the pure build needs no mypy_extensions (it comes with mypy, not with this package).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from mypy_extensions import mypyc_attr as mypyc_attr
else:
    try:
        from mypy_extensions import mypyc_attr
    except ImportError:  # the pure build without mypy installed

        def mypyc_attr(*args, **kwargs):
            return lambda cls: cls


__all__ = ["mypyc_attr"]
