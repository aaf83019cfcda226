"""The daemon's ``GET /gantry`` reads a configured gantry without writing to it (counted at the emulated
bus), and its moves and submissions are refused, with nothing written, while an axis is not referenced."""

from __future__ import annotations

from gonio.config import load_config
from gonio.sim.emulators.dxl_packet import Inst, PacketReader
from gonio.sim.emulators.gantry import EmulatedGantry
from gonio.sim.emulators.link import SyncedVirtualClock

WRITES = {Inst.WRITE, Inst.REG_WRITE, Inst.ACTION, Inst.REBOOT, Inst.SYNC_WRITE}


def _insts(emu) -> list[int]:
    reader = PacketReader()
    return [p.inst for raw in emu.emulators["arm"].received for p in reader.feed(raw)]


def test_get_gantry_writes_nothing_and_moves_are_refused_until_referenced(serve, tmp_path):
    clock = SyncedVirtualClock()
    with EmulatedGantry(load_config("emulated-two-arm-dynamixel"), clock=clock, any_port=True) as emu:
        d = serve(cfg=emu.config(), clock=clock, data=tmp_path / "d")
        for _ in range(2):
            r = d.client.get("/gantry")
            assert r.status_code == 200, r.text
        status = r.json()
        assert status["unreferenced"] == ["light_azimuth", "detector_azimuth"]
        assert status["light"]["on"] is None  # the lamp was not connected to be asked
        insts = _insts(emu)
        assert insts and not set(insts) & WRITES, insts
        for path, body in (("/gantry/home", None), ("/campaigns", {"grid": "iso:step=45", "sample": "s"})):
            r = d.client.post(path, json=body)
            assert r.status_code == 409, r.text
            assert "light_azimuth" in r.json()["detail"] and "gonio gantry reference" in r.json()["detail"]
        assert not set(_insts(emu)) & WRITES
        assert d.client.get("/campaigns").json()["campaigns"] == []
        assert all(s.value(64) == 0 for s in emu.servos.values())  # never energised
