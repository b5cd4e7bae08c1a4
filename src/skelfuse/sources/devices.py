"""What Azure Kinect hardware and software this machine has: ``skelfuse devices``.

:func:`list_devices` opens every connected device briefly (pyk4a; firmware versions through libk4a on the
pyk4a device handle) and reports its serial, firmware and sync jacks. Without pyk4a it falls back to libk4a
alone through ctypes. :func:`describe_environment` says what is installed and, for what is missing, how to
install it. Devices opened by another process (a running capture worker) cannot be opened again: they are
listed with a note instead.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import platform
import sys
from dataclasses import dataclass
from typing import Any

from skelfuse.sources.k4abt import (
    K4A_BUFFER_RESULT_SUCCEEDED,
    K4A_BUFFER_RESULT_TOO_SMALL,
    K4A_RESULT_SUCCEEDED,
    K4ABTError,
    K4abtLibrary,
    K4aHardwareVersion,
    device_handle,
    load_k4a,
)
from skelfuse.sources.kinect import KinectUnavailable

FIRMWARE_BUILDS = ("release", "debug")
FIRMWARE_SIGNATURES = ("msft", "test", "unsigned")


@dataclass(frozen=True)
class FirmwareVersions:
    """``k4a_hardware_version_t`` as text: "major.minor.iteration" per component."""

    rgb: str
    depth: str
    audio: str
    depth_sensor: str
    build: str
    signature: str

    @classmethod
    def from_struct(cls, version: K4aHardwareVersion) -> FirmwareVersions:
        def text(v: Any) -> str:
            return f"{v.major}.{v.minor}.{v.iteration}"

        def name(names: tuple[str, ...], value: int) -> str:
            return names[value] if 0 <= value < len(names) else str(value)

        return cls(
            rgb=text(version.rgb),
            depth=text(version.depth),
            audio=text(version.audio),
            depth_sensor=text(version.depth_sensor),
            build=name(FIRMWARE_BUILDS, version.firmware_build),
            signature=name(FIRMWARE_SIGNATURES, version.firmware_signature),
        )


@dataclass(frozen=True)
class DeviceInfo:
    """One connected device.

    Attributes
    ----------
    index : int
        SDK device index (changes with USB enumeration; configs name serials).
    serial : str or None
        None when the device could not be opened (see ``note``).
    firmware : FirmwareVersions or None
    sync_in_connected, sync_out_connected : bool or None
        A cable is plugged into the "Sync in" / "Sync out" jack. A master has out only, a subordinate in
        (and out unless it ends the chain).
    note : str or None
    """

    index: int
    serial: str | None
    firmware: FirmwareVersions | None = None
    sync_in_connected: bool | None = None
    sync_out_connected: bool | None = None
    note: str | None = None

    @property
    def suggested_role(self) -> str | None:
        """The wired-sync role the jacks suggest (in: subordinate; out only: master; none: standalone)."""
        if self.sync_in_connected is None:
            return None
        if self.sync_in_connected:
            return "subordinate"
        return "master" if self.sync_out_connected else "standalone"


def _firmware(k4a: Any, handle: int) -> FirmwareVersions | None:
    version = K4aHardwareVersion()
    if k4a.k4a_device_get_version(ctypes.c_void_p(handle), ctypes.byref(version)) != K4A_RESULT_SUCCEEDED:
        return None
    return FirmwareVersions.from_struct(version)


def _list_with_pyk4a(pyk4a: Any, k4a: Any) -> list[DeviceInfo]:
    devices = []
    for index in range(int(pyk4a.connected_device_count())):
        device = pyk4a.PyK4A(device_id=index)
        try:
            device.open()
        except pyk4a.K4AException as exc:
            devices.append(
                DeviceInfo(index=index, serial=None, note=f"cannot open ({exc or 'busy'}): in use by another process?")
            )
            continue
        try:
            serial = str(device.serial)
            jack_in, jack_out = device.sync_jack_status
            firmware = None
            if k4a is not None:
                try:
                    firmware = _firmware(k4a, device_handle(device))
                except K4ABTError:
                    firmware = None
            devices.append(
                DeviceInfo(
                    index=index,
                    serial=serial,
                    firmware=firmware,
                    sync_in_connected=bool(jack_in),
                    sync_out_connected=bool(jack_out),
                )
            )
        finally:
            device.close()
    return devices


def _list_with_k4a(k4a: Any) -> list[DeviceInfo]:
    devices = []
    for index in range(int(k4a.k4a_device_get_installed_count())):
        handle = ctypes.c_void_p()
        if k4a.k4a_device_open(index, ctypes.byref(handle)) != K4A_RESULT_SUCCEEDED or not handle.value:
            devices.append(DeviceInfo(index=index, serial=None, note="cannot open: in use by another process?"))
            continue
        try:
            size = ctypes.c_size_t(0)
            serial = None
            if k4a.k4a_device_get_serialnum(handle, None, ctypes.byref(size)) == K4A_BUFFER_RESULT_TOO_SMALL:
                buffer = ctypes.create_string_buffer(size.value)
                if k4a.k4a_device_get_serialnum(handle, buffer, ctypes.byref(size)) == K4A_BUFFER_RESULT_SUCCEEDED:
                    serial = buffer.value.decode(errors="replace")
            jack_in, jack_out = ctypes.c_bool(), ctypes.c_bool()
            jacks_ok = k4a.k4a_device_get_sync_jack(handle, ctypes.byref(jack_in), ctypes.byref(jack_out)) == 0
            devices.append(
                DeviceInfo(
                    index=index,
                    serial=serial,
                    firmware=_firmware(k4a, int(handle.value)),
                    sync_in_connected=bool(jack_in.value) if jacks_ok else None,
                    sync_out_connected=bool(jack_out.value) if jacks_ok else None,
                )
            )
        finally:
            k4a.k4a_device_close(handle)
    return devices


def list_devices(*, pyk4a: Any = None, k4a: Any = None, k4a_path: str | None = None) -> list[DeviceInfo]:
    """Every connected Azure Kinect / Femto Bolt (K4A wrapper), briefly opened.

    Parameters
    ----------
    pyk4a : module, optional
        Injected pyk4a (tests); default ``import pyk4a`` when installed.
    k4a : ctypes.CDLL, optional
        A loaded libk4a (:func:`skelfuse.sources.k4abt.load_k4a`); default: found on the system.

    Raises
    ------
    KinectUnavailable
        Neither pyk4a nor libk4a can be loaded (the message says what to install).
    """
    if k4a is None:
        try:
            k4a = load_k4a(k4a_path)
        except K4ABTError:
            k4a = None
    if pyk4a is None:
        try:
            import pyk4a as imported

            pyk4a = imported
        except ImportError:
            pyk4a = None
    if pyk4a is not None:
        return _list_with_pyk4a(pyk4a, k4a)
    if k4a is not None:
        return _list_with_k4a(k4a)
    raise KinectUnavailable(
        "cannot list Azure Kinect devices: neither pyk4a nor libk4a is installed.\n" + describe_environment()
    )


def format_devices(devices: list[DeviceInfo]) -> str:
    """A table for ``skelfuse devices``."""
    if not devices:
        return "no Azure Kinect device connected (check USB 3 cable, power supply, and `lsusb | grep 045e`)"
    lines = [f"{'#':>2}  {'serial':<14} {'sync in':<8} {'sync out':<8} {'role?':<12} firmware (rgb / depth / audio)"]
    for d in devices:
        fw = "?" if d.firmware is None else f"{d.firmware.rgb} / {d.firmware.depth} / {d.firmware.audio}"

        def jack(v: bool | None) -> str:
            return "?" if v is None else ("yes" if v else "no")

        lines.append(
            f"{d.index:>2}  {d.serial or '-':<14} {jack(d.sync_in_connected):<8} "
            f"{jack(d.sync_out_connected):<8} {d.suggested_role or '?':<12} {fw}" + (f"  ({d.note})" if d.note else "")
        )
    return "\n".join(lines)


def _without_install_hint(message: str) -> str:
    """The reason of a "cannot load" message without its install paragraph (said once, at the end)."""
    return message.split("; install ")[0]


def describe_environment(*, k4a_path: str | None = None, k4abt_path: str | None = None) -> str:
    """What of the Kinect stack is installed here, and how to install what is missing."""
    lines = [f"platform: {platform.system()} {platform.machine()}, Python {sys.version.split()[0]}"]
    linux = sys.platform.startswith("linux")
    ok = True
    try:
        k4a = load_k4a(k4a_path)
        lines.append(f"libk4a (Sensor SDK): found ({getattr(k4a, '_name', '?')})")
    except K4ABTError as exc:
        ok = False
        lines.append(f"libk4a (Sensor SDK): MISSING - {_without_install_hint(str(exc))}")
    try:
        k4abt = K4abtLibrary.load(k4abt_path)
        lines.append(f"libk4abt (Body Tracking SDK): found ({k4abt.path}, ABI {k4abt.abi})")
    except K4ABTError as exc:
        ok = False
        lines.append(f"libk4abt (Body Tracking SDK): MISSING - {_without_install_hint(str(exc))}")
    if importlib.util.find_spec("pyk4a") is None:
        ok = False
        lines.append("pyk4a (skelfuse[kinect] extra): MISSING - pip install 'skelfuse[kinect]' (after the Sensor SDK)")
    else:
        try:
            import pyk4a  # noqa: F401

            lines.append("pyk4a (skelfuse[kinect] extra): installed")
        except ImportError as exc:
            ok = False
            lines.append(
                f"pyk4a: installed but cannot load ({exc}); the Sensor SDK's libk4a must be on the "
                "library path (LD_LIBRARY_PATH / PATH)"
            )
    if linux:
        models = [
            p
            for p in ("/usr/bin/dnn_model_2_0_op11.onnx", "/usr/bin/dnn_model_2_0_lite_op11.onnx")
            if os.path.exists(p)
        ]
        lines.append(
            "body tracking models: "
            + (
                ", ".join(models)
                if models
                else "none in /usr/bin (they come with libk4abt1.1; set sensors[i].kinect.tracker.model_path)"
            )
        )
        if not os.path.exists("/etc/udev/rules.d/99-k4a.rules"):
            lines.append(
                "udev rule: /etc/udev/rules.d/99-k4a.rules missing - without it only root can open the "
                "devices (copy scripts/99-k4a.rules from the Azure-Kinect-Sensor-SDK repository)"
            )
    if not ok:
        if linux:
            lines.append(
                "to install on Ubuntu 18.04/20.04 (22.04: use the 18.04 packages or build from source): add "
                "https://packages.microsoft.com/ubuntu/18.04/prod, then `sudo apt install k4a-tools "
                "libk4a1.4-dev libk4abt1.1-dev`, then `pip install 'skelfuse[kinect]'`"
            )
        elif sys.platform == "win32":
            lines.append(
                "to install on Windows: the Azure Kinect SDK 1.4.1 installer and the Body Tracking SDK 1.1.2 "
                "installer (Microsoft Download Center), add their bin folders to PATH, then "
                "`pip install 'skelfuse[kinect]'`"
            )
        else:
            lines.append("the Azure Kinect SDKs exist for Linux (x86_64) and Windows only")
        lines.append(
            "Femto Bolt / Mega: install Orbbec's OrbbecSDK-K4A-Wrapper (it provides libk4a) instead of the "
            "Sensor SDK. See docs/kinect.md"
        )
    return "\n".join(lines)
