"""The shipped configs, wherever the package is: `configs/` of a source checkout, or the same files installed
with the wheel as the package `pure_hil_configs`. Every command finds a config through `find`, so a name
means the same thing from any folder.

    find("balance", "scenarios")            -> .../scenarios/balance.toml        (a short name)
    find("riders/s07_abi_73kg_176.toml")    -> .../riders/s07_abi_73kg_176.toml  (relative to the configs)
    find("configs/robot/pure.toml")         -> the same file, as the source tree spells it
    find("my/bench.toml")                   -> ./my/bench.toml when it exists there
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from drivers.config import ConfigError


def _shipped() -> Path:
    try:
        return Path(str(importlib.resources.files("pure_hil_configs")))
    except ModuleNotFoundError:  # a source tree on sys.path, not installed
        return Path(__file__).resolve().parents[1] / "configs"


SHIPPED = _shipped()
"""The folder of the shipped configs (kinds: scenarios, riders, robot, benches, campaigns, ...)."""

SUFFIX = {"can": ".dbc", "zenoh": ".json5"}


def find(name: str | Path, kind: str | None = None) -> Path:
    """The config `name` means: an absolute path; a path that exists from the working directory; a path
    inside the shipped configs (with or without a leading `configs/`); or, given its `kind` (the folder:
    "scenarios", "riders", ...), a shipped file's short name. ConfigError lists the shipped names of that
    kind when nothing matches."""
    path = Path(name)
    if path.is_absolute() or path.exists():
        return path
    parts = path.parts[1:] if path.parts[:1] == ("configs",) else path.parts
    candidates = [SHIPPED.joinpath(*parts)] if parts else []
    if kind is not None and len(parts) == 1:
        candidates.append(SHIPPED / kind / f"{parts[0]}{SUFFIX.get(kind, '.toml')}")
    for candidate in candidates:
        if candidate.is_file():
            return candidate
    known = f"; shipped {kind}: {', '.join(shipped(kind))}" if kind else ""
    raise ConfigError(path, f"no such file here or among the shipped configs{known}")


def shipped(kind: str) -> list[str]:
    """Short names of the shipped configs of one kind."""
    return sorted(p.stem for p in (SHIPPED / kind).glob(f"*{SUFFIX.get(kind, '.toml')}"))
