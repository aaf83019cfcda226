"""``gonio gantry status`` asks a rig for its state without energising it: counted at the packet level on
the emulated buses, it sends no write of any kind (no torque, no goal, no watchdog, no marker), on a
Dynamixel bus (servos with torque off, one whose bus watchdog fired) and on Modbus controllers."""

from __future__ import annotations

import json

from gonio.cli import main
from gonio.config import load_config
from gonio.sim.emulators.dxl_packet import Inst, PacketReader
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock

DXL_WRITES = {Inst.WRITE, Inst.REG_WRITE, Inst.ACTION, Inst.REBOOT, Inst.SYNC_WRITE}
#: Modbus function codes that write (coils, registers, read/write).
MODBUS_WRITES = {5, 6, 15, 16, 22, 23}


def dxl_instructions(emu) -> list[int]:
    reader = PacketReader()
    return [p.inst for raw in emu.emulators["arm"].received for p in reader.feed(raw)]


def modbus_functions(motor) -> list[int]:
    return [frame[7] if motor.address is not None else frame[1] for frame in motor.requests]


def test_gantry_status_sends_no_write_on_a_dynamixel_bus(tmp_path, capsys):
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-two-arm-dynamixel"), clock=clock, any_port=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        tilt = emu.servos["light_tilt"]
        assert tilt.value(64) == 0  # powered up: torque off, and it must stay so
        assert tilt.write(64, b"\x01") == 0 and tilt.write(98, b"\x01") == 0  # one armed, ...
        clock.sleep(1.0)
        assert tilt.value(98) == -1  # ... whose watchdog fired since
        before = len(emu.emulators["arm"].received)
        assert main(["gantry", "status", "--config", str(path), "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        assert main(["gantry", "status", "--config", str(path)]) == 0
        text = capsys.readouterr().out
        insts = dxl_instructions(emu)[before:]
        assert insts and set(insts) <= {Inst.PING, Inst.READ, Inst.SYNC_READ}, insts
        assert [i for i in insts if i in DXL_WRITES] == []
        assert tilt.value(98) == -1 and emu.servos["light_azimuth"].value(64) == 0
    axes = {a["axis"]: a for a in report["axes"]}
    assert "watchdog fired" in axes["light_tilt"]["fault"]
    assert axes["detector_azimuth"]["referenced"] is False
    assert "NOT referenced" in text and "gonio gantry reference" in text


def test_gantry_status_sends_no_write_to_modbus_controllers(tmp_path, capsys):
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-sample-stage-modbus"), clock=clock, any_port=True) as emu:
        path = tmp_path / "gantry.toml"
        path.write_text(emu.config_toml())
        emu.motors["sample_tilt"].raise_alarm(0x30)  # an alarm standing: looked at, not reset
        assert main(["gantry", "status", "--config", str(path), "--json"]) == 0
        report = json.loads(capsys.readouterr().out)
        for name, motor in emu.motors.items():
            functions = modbus_functions(motor)
            assert functions and not set(functions) & MODBUS_WRITES, (name, functions)
        assert emu.motors["sample_tilt"].alarm_code == 0x30
    axes = {a["axis"]: a for a in report["axes"]}
    assert axes["sample_tilt"]["fault"] == "controller alarm 0x0030"
    assert axes["changer"]["referenced"] is False
