"""How every process of a bench joins its zenoh (a bench file's `[zenoh]` table): a msgspec Struct, so it
lives apart from drivers/zenoh_link.py, which the compiled build compiles (msgspec does not see the class
keywords of a Struct that mypyc compiled; docs/performance.md "Compiled build")."""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import msgspec
import zenoh

from drivers.zenoh_link import (
    BENCH_CLIENT,
    LOOPBACK,
    ZenohConfigError,
    hub_endpoints,
    lent_session,
    open_hub,
    open_session,
)


class ZenohAccess(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    """How every process of a bench joins its zenoh: `loopback` (the rig is the hub on 127.0.0.1, the others
    join it) or `router` (every process a client of the secured bench router, identified by its role's
    certificate; docs/security.md). A bench file's `[zenoh]` table."""

    mode: Literal["loopback", "router"] = "loopback"
    endpoint: str | None = None
    """loopback: the rig's hub (None: the config's, tcp/127.0.0.1:7447); router: the router's (None: the
    client config's, tls/127.0.0.1:7448)."""
    certs: str | None = None
    """router: the folder of `pure-hil certs init` (a command's --certs fills it)."""
    config: str | None = None
    """A zenoh config file instead of the shipped loopback.json5 / bench-client.json5."""
    network: bool = False
    """The hub (loopback mode) or the router is on another host: its endpoint is not on loopback."""
    prefix: str = "pure"

    @property
    def config_path(self) -> Path:
        return Path(self.config) if self.config else LOOPBACK if self.mode == "loopback" else BENCH_CLIENT

    def open(self, role: str) -> zenoh.Session:
        """A session for one process of the bench in `role` (its certificate on a router; on loopback every
        role but the rig's hub is a member)."""
        if self.mode == "loopback":
            lent = lent_session(self.endpoint)
            if lent is not None:
                return lent
            return open_session(self.config_path, "member", self.endpoint, self.network)
        if self.certs is None:
            raise ZenohConfigError("zenoh mode router needs the certificate folder (--certs DIR)")
        return open_session(
            self.config_path, "member", self.endpoint, self.network, certs=self.certs, identity=role
        )

    def hub_endpoint(self) -> str:
        """loopback: where the rig's hub listens (the bench's endpoint, or its zenoh config's)."""
        return self.endpoint or hub_endpoints(self.config_path)[0]

    def open_rig(self, fallback: bool) -> tuple[zenoh.Session, ZenohAccess]:
        """The rig's session, and the access its other processes use (a loopback hub may have moved to a
        free port: `fallback`, see open_hub)."""
        if self.mode == "router":
            return self.open("rig"), self
        session, endpoint = open_hub(self.config_path, self.endpoint, fallback)
        return session, msgspec.structs.replace(self, endpoint=endpoint)
