"""RealTime cycle rate of the BH8-262 driver against the emulator, beside the wire-limited rate.

The emulator paces every byte at the baud rate both ways, so no client can beat the wire limit
R / (10 * B) for B bytes per cycle; the ratio measured / limit is what the driver and the emulator
lose to everything else (Python, the OS, the twin stepping in real time on the same machine).
The emulator runs in a separate process (`twin emulate hand`), as it would on a lab's second machine.
"""

from __future__ import annotations

import subprocess
import sys
import time

from twin.hardware.bh262.driver import BH262, HandTimeoutError, PortSettings
from twin.hardware.bh262.protocol import FeedbackFormatError, RealTimeConfig

BAUD = 38400
CONFIGS = {
    "hand interface (LCV+LCPG / LFV+LFS+LFAP, 1234)": RealTimeConfig(
        motors=(1, 2, 3, 4), control=("LCV", "LCPG"), feedback=("LFV", "LFS", "LFAP")
    ),
    "manual example (LCV+LCPG / LFS+LFAP, 123)": RealTimeConfig(
        motors=(1, 2, 3), control=("LCV", "LCPG"), feedback=("LFS", "LFAP")
    ),
    "positions only (LCV / LFAP, 1234)": RealTimeConfig(
        motors=(1, 2, 3, 4), control=("LCV",), feedback=("LFAP",)
    ),
}
TRANSPORTS = ("pty", "tcp:0")


def _start_emulator(transport: str) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "twin.cli", "emulate", "hand", "--port", transport, "--object", "block"]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    for line in proc.stdout:
        if line.startswith("hand: "):
            return proc, line.split()[1]
    raise RuntimeError("the emulator did not start")


STOP_TIMEOUT_S = 60.0
"""How long the emulator gets to close after SIGTERM (it opens the twin's fingers in the twin's own
motion time, which a busy machine slows) before it is killed."""


def stop(proc: subprocess.Popen, timeout_s: float | None = None) -> None:
    """End the emulator this benchmark started: SIGTERM, its output drained (a full pipe would keep it
    from exiting), then SIGKILL after `timeout_s`. Never raises: the rows measured are kept whatever
    the emulator does on its way out (a busy machine made `wait(timeout=10)` throw the table away)."""
    proc.terminate()
    try:
        proc.communicate(timeout=STOP_TIMEOUT_S if timeout_s is None else timeout_s)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.communicate()


def _cycle(bh: BH262, config: RealTimeConfig, control: dict) -> bool:
    """One C cycle; a reply lost to a busy machine (later than the driver's allowance) is recovered
    as the hand driver would, and counted, instead of ending the benchmark. True when it was lost."""
    try:
        bh.cycle(control)
        return False
    except (HandTimeoutError, FeedbackFormatError):
        bh.recover_realtime(config)
        return True


def _measure(url: str, config: RealTimeConfig, cycles: int) -> tuple[float, int]:
    bh = BH262(PortSettings(url=url, switch_baud=BAUD, baud_switch_wait_s=0.1))
    bh.open()
    try:
        bh.initialize()
        bh.enter_realtime(config)
        n = len(config.motors)
        control = {f: [0] * n for f in config.control}
        for _ in range(10):  # warm up
            _cycle(bh, config, control)
        t0 = time.perf_counter()
        lost = sum(_cycle(bh, config, control) for _ in range(cycles))
        rate = cycles / (time.perf_counter() - t0)
        bh.leave_realtime()
        return rate, lost
    finally:
        bh.close()


def run(quick: bool = False) -> dict:
    """Cycle rate per RealTime layout and transport at 38400 baud."""
    cycles = 60 if quick else 1500
    rows = []
    for transport in TRANSPORTS[:1] if quick else TRANSPORTS:
        proc, url = _start_emulator(transport)
        try:
            for name, config in CONFIGS.items():
                rate, lost = _measure(url, config, cycles)
                limit = config.wire_limit_hz(BAUD)
                rows.append(
                    {
                        "layout": name,
                        "transport": transport.split(":")[0],
                        "bytes_per_cycle": 1 + config.control_size + config.feedback_size,
                        "limit_hz": limit,
                        "measured_hz": rate,
                        "ratio": rate / limit,
                        "lost_cycles": lost,
                    }
                )
        finally:
            stop(proc)
    return {"baud": BAUD, "cycles": cycles, "rows": rows}


def to_markdown(results: dict) -> str:
    """The BENCHMARKS.md section."""
    lines = [
        "## BH8-262 RealTime cycle rate (driver vs emulator)",
        "",
        f"`C` cycles (control + feedback) at {results['baud']} baud, {results['cycles']} cycles each, "
        "emulator "
        "in its own process. The wire limit is baud / (10 x bytes per cycle), bytes both ways; "
        "the acceptance target is >= 90 % of it. `lost`: replies later than the driver's scheduling "
        "allowance (recovered and counted; a busy machine's, not the wire's).",
        "",
        "| RealTime layout | transport | bytes/cycle | wire limit (Hz) | measured (Hz) | ratio | lost |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in results["rows"]:
        lines.append(
            f"| {r['layout']} | {r['transport']} | {r['bytes_per_cycle']} | {r['limit_hz']:.1f} | "
            f"{r['measured_hz']:.1f} | {r['ratio']:.1%} | {r.get('lost_cycles', 0)} |"
        )
    return "\n".join(lines) + "\n"
