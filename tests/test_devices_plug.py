"""A new device profile is one module plus one entry-point line (issue 38): tests/shifted_profile.py, a lab's
drive profile, installed as `pip install` of the lab's package would install it, is accepted by a bench,
and the rig's emulation and a controller's host exchange real frames through it on an in-process bus."""

from __future__ import annotations

import can
import pytest

from drivers.can_bus import private_channel
from drivers.can_codec import MessageName
from drivers.config import ConfigError
from drivers.devices import controller_frame_ids, host_node
from hil.bench.bench import load_bench
from hil.devices import rig_node

DIST = "shifted_profile-0.1.dist-info"


def _install_entry_point(site, monkeypatch) -> None:
    """What `pip install` of a lab's package leaves: a dist-info with its one entry point, on sys.path."""
    info = site / DIST
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: shifted-profile\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[pure_hil.devices]\nshifted = tests.shifted_profile:PROFILE\n")
    monkeypatch.syspath_prepend(str(site))


def test_a_drive_profile_installed_by_one_entry_point_line_runs_on_the_bus(tmp_path, monkeypatch):
    monkeypatch.setattr("drivers.devices.profile._found", {})  # nothing found earlier outlives this test
    bench = tmp_path / "shifted.toml"
    bench.write_text('name = "shifted"\n[devices]\ndrives = "shifted"\n')
    # Control: before the entry point exists, the bench is refused, naming the profile and the installed ones.
    with pytest.raises(
        ConfigError,
        match=r"shifted\.toml: drives: no drives device profile 'shifted' installed \(have: pure, cia402, "
        r"odrive\) - at `\$\.devices`",
    ):
        load_bench(bench)

    _install_entry_point(tmp_path / "site", monkeypatch)
    devices = load_bench(bench).devices
    assert devices.profiles == ("shifted",) and not devices.pure
    assert controller_frame_ids(devices) == {0x601, 0x602, 0x603}

    channel = private_channel("shifted")
    with (
        can.Bus(interface="virtual", channel=channel) as rig_bus,
        can.Bus(interface="virtual", channel=channel) as controller_bus,
        can.Bus(interface="virtual", channel=channel) as wire,
    ):
        rig = rig_node(rig_bus, devices, 8192, 400.0)
        controller = host_node(controller_bus, devices, 8192, "controller")

        assert controller.send(MessageName.DRIVE2_COMMAND, {"Torque": 1.5, "Enable": 1, "Tick": 0})
        command = rig.recv(1.0)
        assert command is not None and command.name == MessageName.DRIVE2_COMMAND
        assert command.signals["Torque"] == pytest.approx(1.5) and command.signals["Enable"] == 1

        feedback = {"Position": -1234, "Velocity": 2.5, "Enabled": 1, "WatchdogTripped": 0, "Fault": 0}
        assert rig.send(MessageName.DRIVE3_FEEDBACK, {**feedback, "BusPowered": 1})
        read = controller.recv(1.0)
        assert read is not None and read.name == MessageName.DRIVE3_FEEDBACK
        assert read.signals["Position"] == -1234 and read.signals["Velocity"] == pytest.approx(2.5)

        # On the wire: the contract's frames 0x400 up (DRIVE2_COMMAND 0x202, DRIVE3_FEEDBACK 0x183).
        assert [wire.recv(1.0).arbitration_id for _ in range(2)] == [0x602, 0x583]
        assert rig.stats.malformed == controller.stats.malformed == {}


def test_a_new_profiles_settings_are_checked_against_its_own_options_type(tmp_path, monkeypatch):
    monkeypatch.setattr("drivers.devices.profile._found", {})
    _install_entry_point(tmp_path / "site", monkeypatch)
    bench = tmp_path / "shifted.toml"

    def devices(settings: str):
        bench.write_text(f'name = "shifted"\n[devices]\ndrives = "shifted"\n{settings}\n')
        return load_bench(bench).devices

    assert controller_frame_ids(devices("[devices.settings.shifted]\nshift = 0x500")) == {0x701, 0x702, 0x703}
    with pytest.raises(
        ConfigError, match=r"shifted\.toml: settings\.shifted: Expected `int` <= 1404 - at `\$\.shift`"
    ):
        devices("[devices.settings.shifted]\nshift = 0x600")
    with pytest.raises(ConfigError, match=r"settings\.shifted: Object contains unknown field `shfit`"):
        devices("[devices.settings.shifted]\nshfit = 0x500")
    # Its own id check: 0x201 + 0x51F is the contract's CONTROLLER_HEARTBEAT, which stays on the bus.
    with pytest.raises(
        ConfigError, match=r"shift: puts a drive frame on the contract's CONTROLLER_HEARTBEAT"
    ):
        devices("[devices.settings.shifted]\nshift = 0x51F")
    with pytest.raises(
        ConfigError, match=r"settings\.odrive: the odrive profile's settings are \[devices\.odrive\]"
    ):
        devices("[devices.settings.odrive]\nnode_ids = [1, 2, 3]")
    with pytest.raises(
        ConfigError, match=r"settings\.canopen_imu: not a profile this bench's drives or imu speak"
    ):
        devices("[devices.settings.canopen_imu]\nrate_hz = 100")


@pytest.mark.parametrize(
    ("target", "error"),
    [
        ("tests.shifted_profile:shift_of", r"is not a DeviceProfile .*has no name, kind, options, host"),
        ("tests.shifted_profile:nothing", r"entry point 'tests\.shifted_profile:nothing' does not load"),
    ],
)
def test_an_entry_point_that_is_not_a_profile_is_named_broken_not_missing(
    tmp_path, monkeypatch, target, error
):
    monkeypatch.setattr("drivers.devices.profile._found", {})
    info = tmp_path / "site" / "broken_profile-0.1.dist-info"
    info.mkdir(parents=True)
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: broken-profile\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[pure_hil.devices]\nbroken = {target}\n")
    monkeypatch.syspath_prepend(str(tmp_path / "site"))
    bench = tmp_path / "broken.toml"
    bench.write_text('name = "broken"\n[devices]\ndrives = "broken"\n')
    with pytest.raises(ConfigError, match=rf"broken\.toml: drives: device profile 'broken': .*{error}"):
        load_bench(bench)
