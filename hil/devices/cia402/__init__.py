"""Three emulated CiA 402 drives on CANopen, one per omniwheel motor, each a python-canopen `LocalNode` with
the project's EDS (configs/devices/cia402.eds; docs/devices.md).

python-canopen gives the object dictionary, the SDO server (expedited and segmented: a master reads the
device name, the PDO configuration, the identity) and the NMT slave's state. What it leaves to the
application is done here: no Notifier thread (the rig feeds each frame to the canopen Network from
`incoming`), the Network sends through the rig's ProfileNode (its bus, fault hooks and log see every frame),
the heartbeat producer counts ticks instead of running a python-can periodic task, the PDOs follow the
communication and mapping parameters a master writes (checked as CiA 301 asks, compiled, applied: TPDOs at
SYNC or on change, RPDOs on reception, only in OPERATIONAL), the live objects answer SDO from the drive's
state, and the CiA 402 state machine, the plant's feedback, EMCY and the error history are
here.

An RPDO's target torque while OPERATION ENABLED in CST reaches the rig as the contract's DRIVEn_COMMAND
tagged with the current tick (a PDO carries no tick), Enable 1; any other RPDO that carries the controlword
or the target torque as Enable 0.

The package follows CiA's layers, as python-canopen's modules do: network.py (the Network the drives sit
on), objects.py (the object dictionary and state every layer shares), nmt.py, sdo.py, pdo.py, emcy.py (CiA
301), p402.py (the 402 profile's state machine, pure), drive.py (a drive: the layers and the profile) and
translator.py (the three drives as the rig's Translator). `hil.devices.cia402` keeps every name its users
import (the profile's entry point `hil.devices.cia402:emulate`, the tests).
"""

from hil.devices.cia402.drive import ERROR_CODE, Drive
from hil.devices.cia402.emcy import HISTORY, error_register
from hil.devices.cia402.network import RigNetwork
from hil.devices.cia402.nmt import OPERATIONAL, RESET_COMMUNICATION, RESET_NODE, STOP, STOPPED
from hil.devices.cia402.objects import EXTENDED, NO_RTR, VALID
from hil.devices.cia402.p402 import HALT, INTERNAL_LIMIT, makes_torque, next_state, status_word
from hil.devices.cia402.pdo import SUPPORTED_RPDO_TYPES, SUPPORTED_TPDO_TYPES, TORQUE_OBJECTS, Pdo
from hil.devices.cia402.sdo import LOAD, SAVE, SDO_ABORT, Abort
from hil.devices.cia402.translator import Cia402Drives, emulate

__all__ = [
    "ERROR_CODE",
    "EXTENDED",
    "HALT",
    "HISTORY",
    "INTERNAL_LIMIT",
    "LOAD",
    "NO_RTR",
    "OPERATIONAL",
    "RESET_COMMUNICATION",
    "RESET_NODE",
    "SAVE",
    "SDO_ABORT",
    "STOP",
    "STOPPED",
    "SUPPORTED_RPDO_TYPES",
    "SUPPORTED_TPDO_TYPES",
    "TORQUE_OBJECTS",
    "VALID",
    "Abort",
    "Cia402Drives",
    "Drive",
    "Pdo",
    "RigNetwork",
    "emulate",
    "error_register",
    "makes_torque",
    "next_state",
    "status_word",
]
