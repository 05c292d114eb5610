"""Haptics for Tear Cloth: grasp devices, the 1 kHz servo loop and the coupling of eq. (5).

This package owns everything between a hand and the simulation's handle, and nothing of the
simulation itself (the session wires ``ServoLoop.publish``/``ServoLoop.proxy`` to it):

- ``device``: ``HapticDevice`` interface, ``DeviceState``, the ``HapticError`` family;
- ``falcon*``: Novint Falcon (packets, kinematics, FTDI transports, driver, byte-level emulator);
- ``spacemouse``: 3Dconnexion HID pucks (input only); ``virtual``: scripted/keyboard device;
- ``servo``: coupling, mailboxes, servo threads; ``servo_process``: the same servo in a process of
  its own (devices built from ``DeviceSpec``s there, shared-memory exchange, the force zeroed by
  the servo itself when the simulating process stalls or dies); ``forcelog``: CSV/PNG; ``live``: the bimanual
  session over devices (servo timing for the bench is ``tearcloth.bench.servo``, the test fakes
  are in the tests folder).

Pure Python (numpy; pyftdi/hidapi/matplotlib imported only when used), SI units, no bpy.
"""
from . import device
# the device interface's own list (errors, states, the base class): written once, in device.py
from .device import *  # noqa: F401,F403
from .falcon import FalconDevice, assign_hands, open_falcons, read_firmware
from .falcon_emulator import FalconEmulator
from .falcon_transport import Transport, list_falcons, open_transport
from .forcelog import ForceLog
from .servo import HandCoupling, ProxySample, ServoLoop, SimulationMailbox
from .servo_process import DeviceSpec, ServoProcess
from .spacemouse import SpaceMouseDevice, list_spacemice
from .virtual import VirtualDevice

__all__ = [
    *device.__all__,
    "FalconDevice",
    "FalconEmulator",
    "assign_hands",
    "open_falcons",
    "read_firmware",
    "Transport",
    "list_falcons",
    "open_transport",
    "ForceLog",
    "HandCoupling",
    "ProxySample",
    "ServoLoop",
    "SimulationMailbox",
    "DeviceSpec",
    "ServoProcess",
    "SpaceMouseDevice",
    "list_spacemice",
    "VirtualDevice",
]
