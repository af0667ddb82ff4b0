"""The bench file: one description of the bench that every command reads (labgrid's environment file).

    pure-hil run balance --bench vcan            # configs/benches/vcan.toml
    pure-hil run balance --bench my-bench.toml --can socketcan:can0

A bench says where each part runs and how the parts reach each other: the CAN bus (python-can's terms), the
controller under test (embedded in the rig's process, spawned by it, or external), the supervisor (the
same three), zenoh (the loopback hub or the secured router), what a run writes, and whether a person is on
the robot. A scenario says what happens; a bench says on what. Errors name the file, the field and what was
expected; `parts.check` then opens every part once and names the one that cannot open (hil/bench/parts.py).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Literal

import msgspec

from drivers.bounds import Positive
from drivers.bus_config import BusConfig
from drivers.config import ConfigError, load_toml
from drivers.devices import Devices
from drivers.registry import PLANTS, installed
from drivers.resources import find
from drivers.zenoh_access import ZenohAccess
from drivers.zenoh_link import ZenohConfigError, check_endpoint

Where = Literal["embedded", "spawned", "external"]


class _Part(msgspec.Struct, frozen=True, kw_only=True, forbid_unknown_fields=True):
    pass


class ControllerPart(_Part, frozen=True):
    where: Where = "embedded"
    """embedded: a plug in the rig's process (driven by its tick in lockstep); spawned: the rig starts the
    same plug in a process of its own (`pure-hil part controller PLUGIN SPEC.json`), or `command`, and stops
    it after the run; external: the rig waits for one started by someone else."""
    plugin: str = "reference"
    """The entry point in `pure_hil.controllers` (embedded and spawned)."""
    law: Literal["scenario", "hacs", "ihacs"] = "scenario"
    """The reference controller's control law: the scenario's, or this one for every run."""
    config: str = "controller/default.toml"
    robot: str | None = None
    """The robot file the controller builds its model from (None: the plant's; another file tests model
    mismatch)."""
    command: list[str] = []
    """spawned: a program of the lab's own to start instead of the plug (empty: the plug)."""
    boot_timeout: Positive | None = None
    """s the rig waits for the controller's boot-up (None: 10 embedded, 30 spawned, 120 external)."""


class SupervisorPart(_Part, frozen=True):
    where: Where = "embedded"
    """embedded: in the rig's tick; spawned: the rig starts the same plug in a process of its own
    (`pure-hil part supervisor PLUGIN SPEC.json`); external: one runs elsewhere on the bus."""
    plugin: str = "reference"
    """The entry point in `pure_hil.supervisors` (drivers/plugs.py)."""
    config: str = "safety/default.toml"
    """Its rules; a scenario's `[safety]` table overrides them for that scenario's runs."""

    @property
    def plug(self) -> str | None:
        """The plug that judges this bench's runs, as reports and the console name it; None for an external
        supervisor, a process the rig did not start and so cannot name."""
        return None if self.where == "external" else self.plugin


class RealtimePart(_Part, frozen=True):
    """How the rig's loop runs under the real-time clock. Each setting falls back where the machine refuses
    it, and the run's summary says which held (`timing.policy`)."""

    priority: Annotated[int, msgspec.Meta(ge=0, le=99)] = 0
    """SCHED_FIFO priority of the rig's tick thread (1-99; 0: the normal scheduler). Needs CAP_SYS_NICE or
    an rtprio limit (docs/rig.md)."""
    lock_memory: bool = False
    """mlockall for the run: no page fault stalls a tick. Needs CAP_IPC_LOCK or a large enough memlock
    limit."""
    cpu: Annotated[int, msgspec.Meta(ge=0)] | None = None
    """Pin the rig's tick thread to this CPU."""
    sync_allowance: Annotated[float, msgspec.Meta(ge=0.05, le=0.9)] = 0.4
    """The share of a tick's period after its scheduled start by which its SYNC must be out; a tick whose
    SYNC is later is the rig's late tick, and what the controller misses then is not the controller's
    (docs/rig.md "When the rig is late")."""


class OutputsPart(_Part, frozen=True):
    folder: str = "runs"
    """Where a command (run, campaign, compare, calibrate, adversary) puts its output folder when no --out
    is given."""
    can_log: bool = True
    recording: bool = True
    plots: bool = True
    mcap: bool = True
    """run.mcap: CAN frames and signals, zenoh inputs and the trace for Foxglove, PlotJuggler, rerun."""


class Bench(_Part, frozen=True):
    name: str
    description: str = ""
    can: BusConfig = BusConfig(channel="")
    """python-can's interface, channel, bitrate (channel "" on an in-process bus: a private channel per
    run, so two rigs on one machine never share a bus)."""
    controller: ControllerPart = ControllerPart()
    supervisor: SupervisorPart = SupervisorPart()
    devices: Devices = Devices()
    """How the drives and the IMU speak on the bus: the contract's own frames (`pure`), ODrive's CAN Simple
    (`odrive`), ... (docs/devices.md). The rig emulates them; the reference controller and the supervisor
    speak them."""
    zenoh: ZenohAccess = ZenohAccess()
    outputs: OutputsPart = OutputsPart()
    sim: str = "sim/default.toml"
    """The plant's simulation settings (tick rate and seed come from the scenario)."""
    plant: str = "sim"
    """The plant: as the sim file says (`sim`), or an installed one whatever it says (`3d`, MuJoCo; `planar`;
    a lab's own: entry points `pure_hil.plants`)."""
    clock: Literal["scenario", "lockstep", "realtime"] = "scenario"
    realtime: RealtimePart = RealtimePart()
    rider_on_board: bool = False
    """A person sits on the robot: fault injection is refused outright."""
    scenarios: tuple[str, ...] = ()
    """Scenario files (or shipped names) this bench offers beside the shipped scenarios: what a console may
    start (a browser names one of these, never a path of its own)."""

    def __post_init__(self) -> None:
        spawned = [part for part in self.separate() if getattr(self, part).where == "spawned"]
        if spawned and self.can.in_process:
            raise ValueError(
                f"{' and '.join(spawned)}.where = 'spawned' needs a CAN bus shared between processes "
                f"(can.interface = 'socketcan', channel = 'vcan0'), not the in-process {self.can.interface!r}"
            )
        if self.controller.command and self.controller.where != "spawned":
            raise ValueError("controller.command is for controller.where = 'spawned'")
        if self.plant != "sim" and self.plant not in installed(PLANTS):
            raise ValueError(
                f"plant: no plant {self.plant!r} installed (have: sim, {', '.join(installed(PLANTS))})"
            )

    def separate(self) -> list[str]:
        """The parts not in the rig's process."""
        return [p for p in ("controller", "supervisor") if getattr(self, p).where != "embedded"]

    @property
    def self_contained(self) -> bool:
        """Every part in the rig's process: nobody else has to find its hub."""
        return self.controller.where == "embedded" and self.supervisor.where == "embedded"

    def with_overrides(
        self,
        *,
        can: BusConfig | None = None,
        controller: Where | None = None,
        law: str | None = None,
        supervisor: Where | None = None,
        hub: str | None = None,
        certs: str | None = None,
        clock: str | None = None,
        plant: str | None = None,
    ) -> Bench:
        """This bench with a command's overrides applied (None: keep the file's). Checked like the file."""
        parts = msgspec.to_builtins(self)
        if can is not None:
            parts["can"] = msgspec.to_builtins(can)
        for section, key, value in (
            ("controller", "where", controller),
            ("controller", "law", law),
            ("supervisor", "where", supervisor),
            ("zenoh", "endpoint", hub),
            ("zenoh", "certs", certs),
        ):
            if value is not None:
                parts[section][key] = value
        if clock is not None:
            parts["clock"] = clock
        if plant is not None:
            parts["plant"] = plant
        try:
            bench = msgspec.convert(parts, Bench)
        except msgspec.ValidationError as exc:
            raise ConfigError(f"bench {self.name} with the command's options", str(exc)) from exc
        if can is not None:
            _check_interface(bench, "--can")
        return bench


EMBEDDED = "embedded"
"""The default bench: everything in one process (configs/benches/embedded.toml)."""


def load_bench(name: str | Path = EMBEDDED) -> Bench:
    """A bench by path or shipped short name (`embedded`, `vcan`, `secured`); a `.json` file is a bench the
    rig wrote for the processes it spawns (the command's overrides applied). ConfigError names the file and
    the field, also for a bus python-can does not have and a hub off this machine."""
    path = find(name, "benches")
    if path.suffix != ".json":
        bench = load_toml(path, Bench)
    else:
        try:
            bench = msgspec.json.decode(path.read_bytes(), type=Bench)
        except OSError as exc:
            raise ConfigError(path, f"cannot read: {exc.strerror or exc}") from exc
        except msgspec.MsgspecError as exc:
            raise ConfigError(path, str(exc)) from exc
    _check_interface(bench, str(path))
    if bench.zenoh.endpoint is not None:
        # Checked here, not where the zenoh config is opened: that error would name the zenoh config.
        try:
            check_endpoint(bench.zenoh.endpoint, "zenoh.endpoint", bench.zenoh.network)
        except ZenohConfigError as exc:
            raise ConfigError(path, str(exc)) from None
    return bench


def _check_interface(bench: Bench, origin: str) -> None:
    """The bus is one python-can has (its own or a plugin's): else the bench would start and fail on
    opening it, naming neither the file nor the field. `origin`: the file, or `--can`."""
    from can.interfaces import VALID_INTERFACES

    interface = bench.can.interface
    if interface not in VALID_INTERFACES:
        field = "" if origin == "--can" else "can.interface = "
        raise ConfigError(
            origin,
            f"{field}{interface!r}: not a CAN interface python-can has here (one of: "
            f"{', '.join(sorted(VALID_INTERFACES))})",
        )
