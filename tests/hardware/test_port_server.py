"""The port server every emulator shares: it releases each descriptor it owns exactly once."""

import os
import time
import tty

from twin.hardware.emulation import Link, PortServer


class _EndsAtOnce(PortServer):
    """A device that hangs up as soon as it is served (as a `vanish` fault does)."""

    def _session(self, link: Link) -> str:
        return "vanished"


def test_a_pty_whose_session_ended_is_not_closed_again_by_close():
    """The session's end releases the pty; close() must not close the same numbers again, by then
    another port's (a second close hung up a live emulator's pty in the suite, seen as 'port lost')."""
    server = _EndsAtOnce()
    path = server.serve_pty()
    deadline = time.monotonic() + 10
    while os.path.exists(path) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not os.path.exists(path), "the ended session did not release its pty"
    master, slave = os.openpty()  # the lowest free numbers: those the ended session released
    try:
        server.close()
        os.fstat(master), os.fstat(slave)  # still open: close() left them alone
        tty.setraw(slave)
        os.write(master, b"x")
        assert os.read(slave, 1) == b"x"
    finally:
        os.close(master)
        os.close(slave)


class _SlowToStop(PortServer):
    """A device whose session takes a while to notice close() (a busy or starved thread)."""

    def _session(self, link: Link) -> str:
        self.stop_event.wait()
        time.sleep(0.5)
        return "stopped"


def test_close_leaves_a_running_session_its_pty_until_it_ends():
    """A session still running after close() gave up waiting would read and write numbers closed under
    it (and maybe reused): its pty stays open until the session itself ends, then goes."""
    server = _SlowToStop()
    path = server.serve_pty()
    server.close(timeout_s=0.05)
    assert os.path.exists(path), "closed under a running session"
    deadline = time.monotonic() + 10
    while os.path.exists(path) and time.monotonic() < deadline:
        time.sleep(0.01)
    assert not os.path.exists(path), "the session ended but its pty stayed open"
