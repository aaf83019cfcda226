"""Line instruments (pyserial, or PyVISA for VISA resource strings): a light source and detectors, each
speaking the dialect and commands of a TOML profile (``profiles/*.toml``: acknowledging, thorlabs-pm100,
scpi-current-source); :mod:`.config` holds the driver's config models (``driver = "serial"``)."""

from gonio.registry import lazy_attributes

#: Each public name -> the submodule it lives in (imported when the name is first used: the driver's
#: config model, gonio.config reads at every config load, must not import the driver's library).
_EXPORTS = {
    "SerialLightSource": "instruments", "SerialPowerMeter": "instruments",
    "SerialSpectrometer": "instruments", "StreamingPowerMeter": "instruments",
    "StreamReader": "stream", "InstrumentCommError": "line", "InstrumentError": "line",
    "LineInstrument": "line", "DEFAULT_PROFILE": "profile", "PROFILES": "profile",
    "InstrumentProfile": "profile", "load_profile": "profile",
}
__all__ = list(_EXPORTS)
__getattr__ = lazy_attributes(__name__, _EXPORTS)
