"""Load typed configuration from TOML files, with errors that name the file, the field and the expectation.

Shared by the rig, the controller and the supervisor: each decodes the files it reads into its own
msgspec types, so a wrong field fails at start-up with e.g.
    configs/robot/pure.toml: Expected `float` > 0.0 - at `$.ball.mass`
"""

from __future__ import annotations

from pathlib import Path
from typing import TypeVar

import msgspec

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file is missing, not TOML, or does not match its schema."""

    def __init__(self, path: Path | str, detail: str):
        super().__init__(f"{path}: {detail}")
        self.path = Path(path)
        self.detail = detail


def load_toml(path: Path | str, type: type[T]) -> T:
    path = Path(path)
    try:
        raw = path.read_bytes()
    except OSError as exc:
        raise ConfigError(path, f"cannot read: {exc.strerror or exc}") from exc
    return decode_toml(raw, type, path)


def decode_toml(raw: bytes | str, type: type[T], origin: Path | str = "<string>") -> T:
    if isinstance(raw, bytes):
        # A binary file, named as such before the decoder sees it: TOML is UTF-8 text, and what msgspec
        # raises for other bytes differs by version (UnicodeDecodeError in 0.22, DecodeError in 0.23).
        try:
            raw = raw.decode("utf-8")
        except UnicodeDecodeError as exc:
            raise ConfigError(origin, f"not a TOML text file (byte {exc.start} is not UTF-8)") from exc
    try:
        return msgspec.toml.decode(raw, type=type)
    except msgspec.ValidationError as exc:
        raise ConfigError(origin, str(exc)) from exc
    except msgspec.DecodeError as exc:
        raise ConfigError(origin, f"not valid TOML: {exc}") from exc


def dump_toml(record: msgspec.Struct) -> bytes:
    """A record as a config file load_toml reads back equal. TOML has no null: a None field is left out,
    which reads back as its default (None, for every optional field of the configs)."""

    def drop_none(value: object) -> object:
        if isinstance(value, dict):
            return {k: drop_none(v) for k, v in value.items() if v is not None}
        if isinstance(value, list):
            return [drop_none(v) for v in value]
        return value

    return msgspec.toml.encode(drop_none(msgspec.to_builtins(record)))
