"""The emulators' pty link behaves as a serial adapter does when its cable is pulled."""

import os

import pytest

from gonio.sim.emulators.link import PtyLink


def test_a_pulled_link_takes_its_port_name_with_it_so_no_reopen_finds_another_pty():
    """A driver reopening a pulled port must not reach the pty number another process was given since
    (another emulator's servo 1, in a loaded suite): the name goes, as /dev/serial/by-id links do."""
    link = PtyLink("ttyPULL")
    try:
        driver = os.open(link.port, os.O_RDWR | os.O_NOCTTY)
        link.unplug()
        os.close(driver)
        other = os.openpty()                # the pty number the link had is free: often given again
        try:
            assert not os.path.lexists(link.port)
            with pytest.raises(FileNotFoundError):
                os.open(link.port, os.O_RDWR | os.O_NOCTTY)
        finally:
            for fd in other:
                os.close(fd)
        link.replug()
        os.close(os.open(link.port, os.O_RDWR | os.O_NOCTTY))   # plugged in again: its name is back
    finally:
        link.close()


def test_a_read_waiting_while_the_link_is_pulled_never_takes_another_ptys_bytes(monkeypatch):
    """The emulator's reader takes the master's descriptor number, then waits on it. A test pulling the
    cable in that moment closes the number, and the process may give it to another pty at once (another
    emulator's): the waiting reader must not read that pty's bytes as the driver's."""
    import select as select_module

    link = PtyLink("ttyRACE")
    real_select = select_module.select
    other = []

    def pulled_while_waiting(r, w, x, timeout=None):
        if not other:                                   # the interleaving: between taking fd and waiting
            number = link.master
            link.unplug()
            master, slave = os.openpty()
            if master != number:                        # the freed number given to another pty
                os.dup2(master, number)
                os.close(master)
            os.write(slave, b"another emulator's bytes")
            other.extend([number, slave])
        return real_select(r, w, x, timeout)

    monkeypatch.setattr(select_module, "select", pulled_while_waiting)
    try:
        assert link.read(1.0) == b""
        monkeypatch.setattr(select_module, "select", real_select)
        assert os.read(other[0], 100) == b"another emulator's bytes"    # still there for its owner
    finally:
        for fd in other:
            os.close(fd)
        link.close()
