"""Every registry of gonio and its built-in entries: the one place each name is written.

Each registry (a :class:`gonio.registry.Registry`) maps a name users write to where its implementation
lives (a ``"module:attr"`` path, imported only when used), a one-line summary for help text, and the
facts that validation and help need without importing it. CLI choices, help text and config validation
read these; a plugin adds to them without editing gonio (docs/EXTENDING.md). This module imports only
:mod:`gonio.registry` (the standard library): ``gonio <command> --help`` reads it in microseconds.

================  ===================================================  =====================================
registry          target                                               extra
================  ===================================================  =====================================
DESIGNS           a :class:`gonio.kinematics.base.Kinematics`           -
                  subclass (it declares its ``axis_names``)
AXIS_DRIVERS,     the driver's pydantic config model (its ``driver``   -
LIGHT_DRIVERS,    a Literal of the name); its ``build`` makes the
DETECTOR_DRIVERS  device (:mod:`gonio.device_config`)
BUS_DRIVERS       the bus's config model; its ``open`` makes the bus  -
SIM_DETECTORS     a :class:`gonio.sim.detectors.SimDetectorKind`       -
EXPORT_FORMATS    ``export(job, out) -> ExportReport``                 ``file_name``: its name in a campaign
                  (:class:`gonio.export.ExportJob`)                    folder (``gonio simulate --export``,
                                                                       unambiguous: ``.bsdf`` and ``.dat``
                                                                       each name two formats); ``folder``:
                                                                       it writes a folder
PLOT_KINDS        a :class:`gonio.plot.PlotKind`                        -
GRID_KINDS        a :class:`gonio.plan.grids.GridKind`                  ``options`` (tuple), ``size``
                                                                       (``"step"``, ``"stride"`` or
                                                                       ``"budget"``: poses or budget_s)
GRID_OPTIONS      - (documentation of each GRID option)                -
ORDERS            ``order(inputs) -> permutation``                      ``lattice``: needs lines of a lattice
                  (:class:`gonio.plan.build.OrderInputs`)
================  ===================================================  =====================================
"""

from __future__ import annotations

from gonio.registry import Registry

__all__ = ["DESIGNS", "AXIS_DRIVERS", "LIGHT_DRIVERS", "DETECTOR_DRIVERS", "BUS_DRIVERS", "SIM_DETECTORS",
           "EXPORT_FORMATS", "PLOT_KINDS", "GRID_KINDS", "GRID_OPTIONS", "ORDERS"]

# -- gantry designs (config [kinematics] design) -----------------------------------------------------------
DESIGNS = Registry("gantry design")
DESIGNS.add("two-arm", "gonio.kinematics.two_arm:TwoArm",
            "two arms on carriages of one ring around a fixed sample")
DESIGNS.add("sample-stage", "gonio.kinematics.sample_stage:SampleStage",
            "a fixed lamp; the sample turned and tilted under a detector arm")

# -- device drivers (config driver = ...): each entry's target is the driver's config model --------------
AXIS_DRIVERS = Registry("axis driver")
AXIS_DRIVERS.add("sim", "gonio.sim.config:SimAxisConfig", "a simulated axis on the gantry's clock")
AXIS_DRIVERS.add("dynamixel", "gonio.drivers.dynamixel.config:DynamixelAxisConfig",
                 "a Dynamixel X-series servo (XM430, XL430) on a dynamixel bus")
AXIS_DRIVERS.add("modbus", "gonio.drivers.modbus.config:ModbusAxisConfig",
                 "a motor controller on a modbus bus, its registers described by a profile")
LIGHT_DRIVERS = Registry("light driver")
LIGHT_DRIVERS.add("sim", "gonio.sim.config:SimLightConfig", "a simulated lamp ([light.sim])")
LIGHT_DRIVERS.add("serial", "gonio.drivers.serial.config:SerialLightConfig",
                  "a lamp or current source on a serial (or VISA) line, speaking a profile's dialect")
DETECTOR_DRIVERS = Registry("detector driver")
DETECTOR_DRIVERS.add("sim", "gonio.sim.config:SimDetectorConfig",
                     "a simulated detector of the kind [detector.sim] names (SIM_DETECTORS)")
DETECTOR_DRIVERS.add("serial", "gonio.drivers.serial.config:SerialDetectorConfig",
                     "a power meter or spectrometer on a serial (or VISA) line, speaking a profile's dialect")
BUS_DRIVERS = Registry("bus driver")
BUS_DRIVERS.add("dynamixel", "gonio.drivers.dynamixel.config:DynamixelBusConfig",
                "a Dynamixel Protocol 2.0 bus on one serial port")
BUS_DRIVERS.add("modbus", "gonio.drivers.modbus.config:ModbusBusConfig", "a Modbus TCP gateway or RTU line")
BUS_DRIVERS.add("serial", "gonio.drivers.serial.config:SerialBusConfig",
                "a serial port, pyserial URL or VISA resource of one line instrument")

# -- simulated detectors ([detector.sim] kind, gonio simulate --detector) -------------------------------
SIM_DETECTORS = Registry("simulated detector")
SIM_DETECTORS.add("photodiode", "gonio.sim.detectors:PHOTODIODE", "an RGB photodiode (the default)")
SIM_DETECTORS.add("spectrometer", "gonio.sim.detectors:SPECTROMETER",
                  "bands of [detector.sim.spectrometer] (spectral materials)")
SIM_DETECTORS.add("camera", "gonio.sim.detectors:CAMERA",
                  "frames ([detector.sim.camera]) reduced to the sample's mean radiance")

# -- export formats (gonio export --format, gonio simulate --export) ---------------------------------------
EXPORT_FORMATS = Registry("export format")
EXPORT_FORMATS.add("merl", "gonio.export:export_merl",
                   "MERL .binary (f_r on the 90 x 90 x 180 half/difference bins; -1 where there is no data)",
                   file_name="brdf.merl.binary")
EXPORT_FORMATS.add("bsdf", "gonio.export:export_bsdf", "Mitsuba 3 / pbrt-v4 measured-BSDF tensor file, RGB",
                   file_name="brdf.rgb.tensor.bsdf")
EXPORT_FORMATS.add("bsdf-spectral", "gonio.export:export_bsdf_spectral",
                   "the tensor file with spectra (360-830 nm) from R, G, B",
                   file_name="brdf.spectral.tensor.bsdf")
EXPORT_FORMATS.add("radiance", "gonio.export:export_radiance",
                   "a folder of PAB-Opto files, one per incidence (CIE-Y), for Radiance's pabopto2bsdf",
                   file_name="brdf.pabopto", folder=True)
EXPORT_FORMATS.add("csv", "gonio.export:export_csv", "the measured samples, one row each",
                   file_name="brdf.samples.csv")
EXPORT_FORMATS.add("h5", "gonio.export:export_h5", "the sampled dataset itself (brdf.h5 layout)",
                   file_name="brdf.copy.h5")

# -- plot kinds (gonio plot --kind) ----------------------------------------------------------------------
PLOT_KINDS = Registry("plot kind")
PLOT_KINDS.add("polar", "gonio.plot:POLAR", "in-plane f_r for several θi")
PLOT_KINDS.add("hemisphere", "gonio.plot:HEMISPHERE", "f_r over ωo for one ωi (--theta-i, --phi-i)")
PLOT_KINDS.add("merl", "gonio.plot:MERL", "f_r over (θh, θd) at φd = 90°: the usual image of MERL-style data")
PLOT_KINDS.add("reciprocity", "gonio.plot:RECIPROCITY",
               "residual map of f(ωi, ωo) against f(ωo, ωi) (campaigns measured with reciprocity=false)")
PLOT_KINDS.add("albedo", "gonio.plot:ALBEDO", "directional albedo against θi")

# -- grids (GRID strings: gonio plan --help lists them from here) ---------------------------------------
GRID_KINDS = Registry("grid kind")
GRID_KINDS.add("iso", "gonio.plan.grids:ISO",
               "θi, θo in {0, S, 2S, ...} <= theta_max; Δφ = φo − φi in {0, S, ...} < 360°, measured with "
               "φi = 0, φo = Δφ (an isotropic sample)",
               size="step", options=("step", "theta_max", "reciprocity", "mirror", "isotropy", "order"))
GRID_KINDS.add("full", "gonio.plan.grids:FULL",
               "θi, φi, θo, φo on the same S-degree lattice (an anisotropic sample)",
               size="step", options=("step", "theta_max", "reciprocity", "isotropy", "order"))
GRID_KINDS.add("merl", "gonio.plan.grids:MERL",
               "centres of every K-th MERL bin along θh, θd and φd, with φh = 0 (an isotropic sample)",
               size="stride", options=("stride", "theta_max", "reciprocity", "isotropy", "order"))
GRID_KINDS.add("adaptive", "gonio.plan.grids:ADAPTIVE",
               "a pilot lattice, then rounds of poses placed where the samples so far are least trustworthy "
               "(peak, Fresnel rise, grazing), until the budget is spent (an isotropic sample, or with "
               "anisotropic=true an anisotropic one; gonio.adaptive)",
               size="budget", options=("poses", "budget_s", "theta_max", "anisotropic", "isotropy", "order"))

GRID_OPTIONS = Registry("grid option")
GRID_OPTIONS.add("step", None, "S degrees, > 0, <= 90 and dividing 360 (so that −Δφ and φ + 180° stay on the "
                 "grid); required")
GRID_OPTIONS.add("stride", None, "K, an integer from 1 to 90; required")
GRID_OPTIONS.add("poses", None, "N, an integer from 1 to 100,000: the poses measured in all, pilot included "
                 "(adaptive; this or budget_s)")
GRID_OPTIONS.add("budget_s", None, "T seconds of estimated gantry time, > 0 and <= 2,592,000 (30 days), "
                 "pilot included (adaptive; this or poses)")
GRID_OPTIONS.add("theta_max", None, "degrees in (0, 90]; default: the config's kinematics.theta_max_deg")
GRID_OPTIONS.add("reciprocity", None, "true|false, default true: measure one pose of each Helmholtz pair "
                 "(ωi, ωo) ~ (ωo, ωi)")
GRID_OPTIONS.add("mirror", None, "true|false, default false: also identify Δφ with −Δφ (a sample symmetric "
                 "about its plane of incidence)")
GRID_OPTIONS.add("anisotropic", None, "true|false, default false: place the poses over the 4D domain "
                 "(θi, φi, θo, φo) with reciprocity only, the pilot a full:step=S grid (adaptive)")
GRID_OPTIONS.add("isotropy", None, "the isotropy the kind assumes (true for iso and merl, false for full): "
                 "accepted for clarity, it changes nothing; the other value is refused")
GRID_OPTIONS.add("order", None, "the order the poses are measured in, default auto (the orders below)")

#: Orders of a GRID's ``order`` option: ``order(inputs)`` (:class:`gonio.plan.build.OrderInputs`) returns
#: a permutation of the poses. ``auto`` is resolved by the grid kind (:class:`gonio.plan.grids.GridKind`);
#: ``fly`` plans the serpentine, whose lines a fly campaign sweeps (``lattice``: grids with lines only).
ORDERS = Registry("order")
ORDERS.add("auto", None, "serpentine sweeps (full; iso unless the tour is estimated quicker, up to "
           "10,000 poses), a tour (merl, each phase of adaptive)")
ORDERS.add("serpentine", "gonio.plan.build:order_serpentine",
           "sweep the grid's innermost loop back and forth, cut where sweeping is cheapest")
ORDERS.add("raster", "gonio.plan.build:order_raster", "the grid's loops in their natural order")
ORDERS.add("tour", "gonio.plan.build:order_tour",
           "the shortest tour found through the poses (merl: up to 50,000 poses)")
ORDERS.add("fly", "gonio.plan.build:order_serpentine",
           "the serpentine's poses read while one axis sweeps each line (iso and full)", lattice=True)
