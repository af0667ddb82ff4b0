"""What the plant's drive state does to an emulated drive, the same for every device profile: the faults
its DRIVEn_FEEDBACK values this tick put on the drive, in one order, which each profile names in its own
error codes (hil/devices/cia402/drive.py, odrive.py)."""

from __future__ import annotations

from collections.abc import Mapping
from enum import Enum


class PlantFault(Enum):
    UNPOWERED = "the drives' DC bus is off (the main contactor open, or a lost supply)"
    WATCHDOG = "the drive's command watchdog tripped"
    POWER_STAGE = "the drive's power stage is faulty (a fault injected in the plant)"


def plant_faults(s: Mapping[str, float]) -> list[PlantFault]:
    """The faults the plant's drive state `s` (DRIVEn_FEEDBACK's values) puts on the drive this tick, the
    most fundamental first (a drive without power also misses its commands)."""
    found = []
    if not s["BusPowered"]:
        found.append(PlantFault.UNPOWERED)
    if s["WatchdogTripped"]:
        found.append(PlantFault.WATCHDOG)
    if s.get("Fault", 0):
        found.append(PlantFault.POWER_STAGE)
    return found
