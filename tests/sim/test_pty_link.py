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
