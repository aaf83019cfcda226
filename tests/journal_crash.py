"""A process death simulated in-process: every journal the code under test creates or opens for writing
gets a write hook that raises :class:`Crash` before the chosen write statement (counted across all the
journals of one "process", creation included), so the transaction in flight is never committed, as when
the process is killed there. The code under test closes what it holds on the way out (its connection, the
folder's lock), as the kernel does for a killed process; the next run resumes from what the journal
committed. A module of its own (imported by this unique name from any test folder)."""

from __future__ import annotations

import contextlib

from gonio.store import Journal


class Crash(BaseException):
    """A simulated process death: nothing catches it, the open transaction is never committed."""


class Writes:
    """The journal writes of one simulated process so far: ``count`` in all, ``creation`` of them while a
    journal was being created."""

    def __init__(self):
        self.count = 0
        self.creation = 0
        self.dead = False

    def die(self):
        """The process dies here, between two writes (e.g. while it computes): :class:`Crash` now, and
        at every later write (the code under test's clean-ups write nothing)."""
        self.dead = True
        raise Crash


@contextlib.contextmanager
def crash_at_write(monkeypatch, at: int | None):
    """Within the block, raise :class:`Crash` before the ``at``-th journal write of the process and every
    later one (``None``: never; only count them). Yields the :class:`Writes` counted so far."""
    writes = Writes()
    create, open_ = Journal.create.__func__, Journal.open.__func__

    def hook(_n: int) -> None:
        writes.count += 1
        if writes.dead or (at is not None and writes.count >= at):
            raise Crash   # and at every later write: a dead process writes nothing more (clean-ups included)

    def hooked_create(cls, path, meta, steps, *, write_hook=None):
        assert write_hook is None, "the code under test brings its own write hook"
        before = writes.count
        try:
            return create(cls, path, meta, steps, write_hook=hook)
        finally:
            writes.creation += writes.count - before

    def hooked_open(cls, path, *, write_hook=None, readonly=False):
        assert write_hook in (None, hook), "the code under test brings its own write hook"
        return open_(cls, path, write_hook=None if readonly else hook, readonly=readonly)

    with monkeypatch.context() as m:
        m.setattr(Journal, "create", classmethod(hooked_create))
        m.setattr(Journal, "open", classmethod(hooked_open))
        yield writes
