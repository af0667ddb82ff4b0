"""mypyc's class options for the plant's compiled modules (setup.py), and a no-op where mypy_extensions is
missing: drivers/native.py's twin (plant/ imports nothing of the rig's packages: tests/test_boundaries.py).

`@mypyc_attr(allow_interpreted_subclasses=True)` lets Python classes derive from a compiled class (the
benchmark's timed `Plant`, a test's watched `MotorDrive`). mypyc reads it when it compiles; at run time it
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
