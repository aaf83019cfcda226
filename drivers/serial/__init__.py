"""Line instruments (pyserial, or PyVISA for VISA resource strings): a light source and detectors, each
speaking the dialect and commands of a TOML profile (``profiles/*.toml``: acknowledging, thorlabs-pm100,
scpi-current-source)."""

from gonio.drivers.serial.instruments import SerialLightSource, SerialPowerMeter, SerialSpectrometer
from gonio.drivers.serial.line import InstrumentCommError, InstrumentError, LineInstrument
from gonio.drivers.serial.profile import DEFAULT_PROFILE, PROFILES, InstrumentProfile, load_profile

__all__ = ["SerialLightSource", "SerialPowerMeter", "SerialSpectrometer", "InstrumentCommError",
           "InstrumentError", "LineInstrument", "DEFAULT_PROFILE", "PROFILES", "InstrumentProfile",
           "load_profile"]
