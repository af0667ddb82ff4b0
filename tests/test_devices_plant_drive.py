"""The plant's drive state reaches every emulated drive the same way (hil/devices/plant_drive.py): the same
faults in the same order, each named in every profile's own error codes."""

from __future__ import annotations

import pytest

from drivers.devices.cia402 import ErrorCode
from drivers.devices.odrive import AxisError
from hil.devices import cia402, odrive
from hil.devices.plant_drive import PlantFault, plant_faults

HEALTHY = {"Position": 0.0, "Velocity": 0.0, "BusPowered": 1, "WatchdogTripped": 0, "Fault": 0}


@pytest.mark.parametrize(
    ("changes", "faults"),
    [
        ({}, []),
        ({"Fault": 1}, [PlantFault.POWER_STAGE]),
        ({"WatchdogTripped": 1}, [PlantFault.WATCHDOG]),
        ({"BusPowered": 0, "WatchdogTripped": 1}, [PlantFault.UNPOWERED, PlantFault.WATCHDOG]),
        ({"BusPowered": 0, "WatchdogTripped": 1, "Fault": 1}, list(PlantFault)),
    ],
)
def test_the_plants_drive_state_puts_its_faults_on_a_drive_most_fundamental_first(changes, faults):
    assert plant_faults(HEALTHY | changes) == faults
    assert plant_faults({k: v for k, v in (HEALTHY | changes).items() if k != "Fault"}) == [
        f for f in faults if f is not PlantFault.POWER_STAGE
    ]  # a profile whose feedback carries no Fault


def test_every_profile_names_every_fault_of_the_plant_in_its_own_codes():
    assert cia402.ERROR_CODE == {
        PlantFault.UNPOWERED: ErrorCode.DC_LINK_UNDER_VOLTAGE,
        PlantFault.WATCHDOG: ErrorCode.COMMUNICATION,
        PlantFault.POWER_STAGE: ErrorCode.POWER_SECTION,
    }
    assert odrive.AXIS_ERROR == {
        PlantFault.UNPOWERED: AxisError.DC_BUS_UNDER_VOLTAGE,
        PlantFault.WATCHDOG: AxisError.WATCHDOG_TIMER_EXPIRED,
        PlantFault.POWER_STAGE: AxisError.DRV_FAULT,
    }
