"""Line-based serial instruments (pyserial): a light source and detectors, with command sets as data."""

from gonio.drivers.serial.instruments import SerialLightSource, SerialPowerMeter, SerialSpectrometer
from gonio.drivers.serial.line import SCPI, CommandSet, InstrumentCommError, InstrumentError, LineInstrument

__all__ = ["SerialLightSource", "SerialPowerMeter", "SerialSpectrometer", "SCPI", "CommandSet",
           "InstrumentCommError", "InstrumentError", "LineInstrument"]
