"""The port server every emulator shares: it releases each descriptor it owns exactly once."""

import os
import time
import tty

from hardware.emulation import Link, PortServer


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
