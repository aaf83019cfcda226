"""``gonio emulate`` as a user runs it, in this process: a dead emulator is said at once in one line
(exit 1) and everything else stops with it; SIGINT and SIGTERM still stop it cleanly (exit 0); a Modbus
port another server holds is refused before anything serves (exit 2).

The emulators' deaths are injected (a bug in a serving loop: nothing a driver sends kills one, see
tests/sim/test_emulator_threads.py). Every wait is bounded; every emulator is stopped by the command.
"""

from __future__ import annotations

import os
import signal
import socket
import threading

import pytest
from cli_helpers import one_clear_line

from gonio.cli import main
from gonio.config import load_config
from gonio.sim.emulators.dynamixel import DynamixelBusEmulator
from gonio.sim.emulators.gantry import to_toml
from gonio.sim.emulators.instruments import LightSourceEmulator

CONFIG = "emulated-two-arm-dynamixel"
SERVOS = "the Dynamixel servos of light_azimuth, light_tilt, detector_azimuth, detector_tilt, changer"
#: A bound on the command's run: it ends within ms of the injected death or signal.
WAIT_S = 30.0


def _served(out: str) -> list[str]:
    """The ports ``gonio emulate`` said it serves (``bus: port`` lines)."""
    return [line.split(": ", 1)[1] for line in out.splitlines()
            if line.split(":", 1)[0] in ("arm", "lamp", "photodiode")]


@pytest.fixture
def emulator_threads():
    """The emulator threads started during the test that are still alive (a call: at the end, none)."""
    before = set(threading.enumerate())
    return lambda: [t.name for t in threading.enumerate() if t not in before and t.name.startswith("emu-")]


def _bounded(argv: list[str]) -> list[int]:
    """``gonio <argv>`` in a thread of its own (no signal handlers there), waited for at most WAIT_S: its
    exit code in a list, empty if it had not returned (it would serve on until a signal)."""
    result: list[int] = []
    command = threading.Thread(target=lambda: result.append(main(argv)), daemon=True)
    command.start()
    command.join(WAIT_S)
    return result


def _when_config_written(monkeypatch, target, act) -> list[bool]:
    """The bus emulator's loop calls ``act()`` once ``target`` exists (the command wrote its config), then
    serves on; the list returned holds True once it did."""
    real_step, done = DynamixelBusEmulator.step, []

    def step(self):
        if not done and target.exists():
            done.append(True)
            act()
        real_step(self)

    monkeypatch.setattr(DynamixelBusEmulator, "step", step)
    return done


def test_an_emulator_that_dies_is_one_line_exit_1_and_the_rest_stops_and_the_config_goes(
        tmp_path, capsys, monkeypatch, emulator_threads):
    """The servos' emulator dies of a bug after the config was written: one line naming the servos, their
    bus and the exception (its two lines joined), exit 1, every pty closed, the config removed. Before,
    the command went on serving the lamp and the photodiode, silent, until a signal (the thread's
    exception kept where nobody looked): the command never returned."""
    target = tmp_path / "emu.toml"

    def bug():
        raise RuntimeError("injected: a bug in the serving loop\nits second line")

    done = _when_config_written(monkeypatch, target, bug)
    assert _bounded(["emulate", "--config", CONFIG, "--write-config", str(target)]) == [1]
    assert done == [True]
    captured = capsys.readouterr()
    assert captured.err == (f"gonio emulate: {SERVOS} (bus 'arm') stopped answering: its emulator died of "
                            "RuntimeError: injected: a bug in the serving loop its second line; every other "
                            f"emulator stopped; {target} removed\n")
    assert f"config: {target}" in captured.out and not list(tmp_path.iterdir())
    ports = _served(captured.out)
    assert len(ports) == 3 and not [p for p in ports if os.path.lexists(p)]
    assert emulator_threads() == []


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_a_signal_stops_every_emulator_and_removes_the_config_exit_0(tmp_path, capsys, monkeypatch, signum,
                                                                    emulator_threads):
    """SIGTERM or SIGINT (sent once the config is written): exit 0, as `gonio serve` on a signal (stopping
    is how a server ends; a campaign cut short is 130), no line on stderr, every pty closed, the config
    removed."""
    assert threading.current_thread() is threading.main_thread()  # the command's handlers are installed
    target = tmp_path / "emu.toml"
    done = _when_config_written(monkeypatch, target, lambda: os.kill(os.getpid(), signum))
    assert main(["emulate", "--config", CONFIG, "--write-config", str(target)]) == 0
    captured = capsys.readouterr()
    assert done == [True] and captured.err == ""
    assert f"config: {target}" in captured.out
    ports = _served(captured.out)
    assert len(ports) == 3 and not [p for p in ports if os.path.lexists(p)]
    assert not target.exists() and emulator_threads() == []


def test_a_modbus_port_another_server_holds_is_one_line_exit_2_before_anything_serves(tmp_path, capsys,
                                                                                    emulator_threads):
    """The shipped Modbus stage's rotation controller on a port this test listens on: refused in one line
    naming the bus, the address and --any-port (exit 2); before, its server's thread died with a
    traceback while the command said it emulated (and served on: it never returned), and `gonio run`
    timed out."""
    data = load_config("emulated-sample-stage-modbus").model_dump(mode="json")
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen(1)
        port = holder.getsockname()[1]
        data["buses"]["rotation"]["url"] = f"tcp://127.0.0.1:{port}"
        config = tmp_path / "stage.toml"
        config.write_text(to_toml(data))
        target = tmp_path / "emu.toml"
        assert _bounded(["emulate", "--config", str(config), "--write-config", str(target)]) == [2]
    one_clear_line(capsys, "gonio emulate: buses.rotation: modbus emulator: cannot listen on "
                   f"127.0.0.1:{port} (address already in use)", "--any-port")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["stage.toml"]
    assert emulator_threads() == []


def test_an_emulator_that_does_not_stop_in_time_is_one_line_exit_1(tmp_path, capsys, monkeypatch,
                                                                    emulator_threads):
    """A signal while the lamp's emulator is busy past the stop's wait (as a PM100 averaging for minutes
    on the wall clock): one line naming it, exit 1, the others stopped, its port and the config gone;
    before, a traceback. (The wait is cut to 0.05 s here; the busy lamp is released at the end.)"""
    assert threading.current_thread() is threading.main_thread()
    target, lamp_busy, release = tmp_path / "emu.toml", threading.Event(), threading.Event()
    real_step, real_stop = LightSourceEmulator.step, LightSourceEmulator.stop

    def lamp_step(self):
        if target.exists() and not release.is_set():
            lamp_busy.set()
            release.wait(WAIT_S)  # busy until the test releases it
        real_step(self)

    def busy_then_signal():  # the signal once the lamp is busy
        assert lamp_busy.wait(WAIT_S)
        os.kill(os.getpid(), signal.SIGTERM)

    monkeypatch.setattr(LightSourceEmulator, "step", lamp_step)
    monkeypatch.setattr(LightSourceEmulator, "stop", lambda self, timeout_s=5.0: real_stop(self, 0.05))
    _when_config_written(monkeypatch, target, busy_then_signal)
    try:
        assert main(["emulate", "--config", CONFIG, "--write-config", str(target)]) == 1
    finally:
        release.set()
    captured = capsys.readouterr()
    assert captured.err == ("gonio emulate: emulator 'LAMP' did not stop within 0.05 s; the others stopped, "
                            "and it ends with this process\n")
    ports = _served(captured.out)
    assert len(ports) == 3 and not [p for p in ports if os.path.lexists(p)] and not target.exists()
    for thread in threading.enumerate():
        if thread.name == "emu-LAMP":
            thread.join(WAIT_S)  # released: it sees its stop and ends
    assert emulator_threads() == []


def test_a_bad_material_names_the_material_option(capsys):
    assert main(["emulate", "--config", "sim", "--material", "ggz:alpha=0.2"]) == 2
    one_clear_line(capsys, "gonio emulate: --material: unknown material model 'ggz'")


def test_the_config_of_a_running_emulator_is_not_taken_over(tmp_path, capsys):
    """A second `gonio emulate --write-config` to the same file replaced the first one's config, and
    removed it when it stopped: the first one's devices were left without one. The file's first line
    names the emulator that wrote it; while that one runs (a waiting child process stands in for it),
    the file is refused, left as it was."""
    import subprocess
    import sys

    target = tmp_path / "emu.toml"
    other = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    try:
        target.write_text(f"# sim-two-arm, emulated by gonio emulate (pid {other.pid}); valid while it "
                          "runs\n")
        before = target.read_bytes()
        assert main(["emulate", "--config", "sim", "--write-config", str(target)]) == 2
        one_clear_line(capsys, f"gonio emulate: --write-config: {target} is the config of the gonio emulate "
                               f"that runs as pid {other.pid}")
        assert target.read_bytes() == before
    finally:
        other.stdin.close()
        other.wait(10)
