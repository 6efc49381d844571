#!/usr/bin/env python3
"""Build two BH8-262 clients nobody here wrote from local copies of their sources, and run them
against `twin emulate hand` on a pseudo-terminal, printing every call, exchange and result.

  - Barrett's BHand API 4.4.3 (Slifer64/DMP_KF at 966cef45e197, c++/dmp_kf/robots/bhand/bhand_lib):
    InitSoftware, InitHand, supervisory calls, RTSetFlags + RTStart + N RTUpdate + RTAbort, at each
    baud rate asked for (9600 without a switch; others with the API's own Baud() call).
  - dmiller12/libgripper (its libgripper/ directory): BarrettHand::initialize(), then its velocity
    mode and its position mode for about N cycles each, at 9600 baud (the rate initialize() opens).

Nothing is fetched: give the source paths. Needs g++, Boost headers (libboost-dev: Asio, Outcome,
Optional) and Poco Foundation (libpoco-dev). Neither client is modified; the shims in shim/ are ours
(a stand-in libpcan.h for the API's unused CAN driver, and an LD_PRELOAD that maps the API's fixed
/dev/ttyUSB9 onto the emulator's pty). Exit status 0 when every acceptance check printed at the end
passed.

  .venv/bin/python tools/third_party_clients/build_and_run.py \\
      --bhand /work/thirdparty/bhand/c++/dmp_kf/robots/bhand/bhand_lib \\
      --libgripper /work/thirdparty/libgripper/libgripper
"""

from __future__ import annotations

import argparse
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
BHAND_SOURCES = (
    "src/source_list/*.cpp",
    "include/bhand_lib/API/src/*.cpp",
    "include/bhand_lib/API/src/linux/*.cpp",
)
LIBGRIPPER_SOURCES = (
    "src/barrett/barrett_hand.cpp",
    "src/barrett/barrett_hand_driver.cpp",
    "src/barrett/position_controller.cpp",
    "src/barrett/velocity_controller.cpp",
    "src/communication/serial_communicator.cpp",
)
MAPPED_PORT = "/dev/ttyUSB9"
"""What `InitSoftware(-9, ...)` opens; portmap.so sends it to the emulator's pty."""
BHAND_CYCLE_BYTES = 9 + 18
"""Barrett client's RealTime cycle: 'C' + LCV, LCPG for 4 motors out; '*' + LFV, LFS, LFAP x 4 + LFT back."""
LIBGRIPPER_CYCLE_BYTES = 6 + 10
"""libgripper's cycle: 'C' + LCV x 3 + LCT (2 bytes) out; '*' + LFAP x 4 + LFT back."""
HEADERS = {"Boost (libboost-dev)": "boost/asio/serial_port.hpp", "Poco (libpoco-dev)": "Poco/Thread.h"}


def fail(message: str) -> None:
    print(f"build_and_run: error: {message}", file=sys.stderr)
    sys.exit(2)


def run(cmd: list[str], **kwargs) -> None:
    result = subprocess.run(cmd, capture_output=True, text=True, **kwargs)
    if result.returncode != 0:
        fail(f"{' '.join(cmd[:3])} ... failed:\n{result.stderr[-3000:]}")


def check_toolchain() -> None:
    if shutil.which("g++") is None:
        fail("g++ not found")
    for name, header in HEADERS.items():
        if not any((Path(d) / header).exists() for d in ("/usr/include", "/usr/local/include")):
            fail(f"{name} headers not found ({header}); e.g. apt-get install libboost-dev libpoco-dev")


def compile_objects(sources: list[Path], out: Path, flags: list[str]) -> list[Path]:
    """Compile each source (skipping those already built from an unchanged file)."""
    out.mkdir(parents=True, exist_ok=True)
    objects = []
    for src in sources:
        obj = out / (src.stem + ".o")
        if not obj.exists() or obj.stat().st_mtime < src.stat().st_mtime:
            run(["g++", *flags, "-w", "-O2", "-c", str(src), "-o", str(obj)])
        objects.append(obj)
    return objects


def build_bhand(src: Path, build: Path) -> Path:
    api = src / "include/bhand_lib/API"
    if not (src / "src/source_list/BHandSerialDriver.cpp").exists():
        fail(f"--bhand {src}: no src/source_list/BHandSerialDriver.cpp (want the bhand_lib directory)")
    flags = ["-std=c++11", "-DLINUX", f"-I{HERE / 'shim'}", f"-I{api}", f"-I{api / 'ctb-0.14'}"]
    sources = sorted(p for pattern in BHAND_SOURCES for p in src.glob(pattern))
    objects = compile_objects(sources, build / "bhand", flags)
    client = build / "bhand_client"
    run(
        [
            *("g++", *flags, "-w", "-O2", str(HERE / "bhand_client.cpp"), *map(str, objects)),
            *("-lPocoFoundation", "-lpthread", "-o", str(client)),
        ]
    )
    run(
        [
            "gcc",
            "-shared",
            "-fPIC",
            "-O2",
            str(HERE / "shim/portmap.c"),
            "-ldl",
            "-o",
            str(build / "portmap.so"),
        ]
    )
    return client


def build_libgripper(src: Path, build: Path) -> Path:
    if not (src / "src/barrett/barrett_hand_driver.cpp").exists():
        fail(f"--libgripper {src}: no src/barrett/barrett_hand_driver.cpp (want its libgripper/ directory)")
    flags = ["-std=c++14", f"-I{src / 'include'}"]
    objects = compile_objects([src / s for s in LIBGRIPPER_SOURCES], build / "libgripper", flags)
    client = build / "libgripper_client"
    run(
        [
            "g++",
            *flags,
            "-w",
            "-O2",
            str(HERE / "libgripper_client.cpp"),
            *map(str, objects),
            "-lpthread",
            "-o",
            str(client),
        ]
    )
    return client


class Emulator:
    """`twin emulate hand` on a pty, its output echoed with a prefix and kept for the checks."""

    def __init__(self, twin: str, baud: int) -> None:
        self.lines: list[str] = []
        self.proc = subprocess.Popen(
            [twin, "emulate", "hand", "--baud", str(baud), "--duration", "900"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            bufsize=1,
        )
        self.pty = ""
        ready = threading.Event()

        def pump() -> None:
            for line in self.proc.stdout:
                line = line.rstrip("\n")
                self.lines.append(line)
                print(f"  | {line}", flush=True)
                m = re.match(r"hand: (/dev/\S+)", line)
                if m:
                    self.pty = m.group(1)
                if line.startswith("ready"):
                    ready.set()
            ready.set()

        threading.Thread(target=pump, daemon=True).start()
        if not ready.wait(60) or not self.pty:
            self.stop()
            fail("the emulator did not come up (see its output above)")

    def loop_counts(self) -> list[int]:
        return [int(m.group(1)) for ln in self.lines if (m := re.search(r"RealTime: (\d+) blocks", ln))]

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def run_client(cmd: list[str], env: dict[str, str] | None, timeout_s: float) -> tuple[int, str]:
    print(f"$ {' '.join(cmd)}", flush=True)
    proc = subprocess.Popen(
        cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, bufsize=1
    )
    out = []
    timer = threading.Timer(timeout_s, proc.kill)
    timer.start()
    for line in proc.stdout:
        out.append(line)
        print(f"  {line}", end="", flush=True)
    timer.cancel()
    return proc.wait(), "".join(out)


def main() -> int:
    import os

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--bhand", type=Path, help="Barrett's bhand_lib directory (BHand API 4.4.3 sources)")
    ap.add_argument("--libgripper", type=Path, help="libgripper's libgripper/ directory")
    ap.add_argument("--build-dir", type=Path, default=Path("/tmp/third_party_clients_build"))
    ap.add_argument("--twin", default=str(Path(sys.executable).parent / "twin"), help="the twin command")
    ap.add_argument("--bauds", default="9600,38400", help="Barrett API rates (default 9600,38400)")
    ap.add_argument("--cycles", type=int, default=1000, help="Barrett API RTUpdate cycles (default 1000)")
    ap.add_argument("--gripper-cycles", type=int, default=2000, help="libgripper cycles per mode (2000)")
    args = ap.parse_args()
    if not args.bhand and not args.libgripper:
        fail("give --bhand and/or --libgripper")
    check_toolchain()
    checks: list[tuple[str, bool]] = []

    if args.bhand:
        client = build_bhand(args.bhand.resolve(), args.build_dir)
        for baud in (int(b) for b in args.bauds.split(",")):
            print(f"\n=== Barrett BHand API 4.4.3 at {baud} baud ===", flush=True)
            emulator = Emulator(args.twin, 9600)  # the hand powers up at 9600; the API switches with Baud()
            env = dict(
                os.environ,
                LD_PRELOAD=str(args.build_dir / "portmap.so"),
                PORTMAP_FROM=MAPPED_PORT,
                PORTMAP_TO=emulator.pty,
            )
            try:
                rc, out = run_client([str(client), str(baud), str(args.cycles)], env, 300)
            finally:
                time.sleep(0.3)
                emulator.stop()
            m = re.search(r"RESULT bhand baud=\d+ cycles=\d+ rate=([\d.]+) failures=(\d+)", out)
            limit = baud / (10 * BHAND_CYCLE_BYTES)
            rate = float(m.group(1)) if m else 0.0
            ok = rc == 0 and m is not None and m.group(2) == "0"
            checks.append((f"BHand API at {baud}: every call returned 0 (exit {rc})", ok))
            checks.append(
                (
                    f"BHand API at {baud}: {rate:.1f} cycles/s = {100 * rate / limit:.1f} % of the "
                    f"wire limit {limit:.1f}/s",
                    baud != 38400 or rate >= 0.9 * limit,
                )
            )

    if args.libgripper:
        client = build_libgripper(args.libgripper.resolve(), args.build_dir)
        print("\n=== libgripper BarrettHand at 9600 baud ===", flush=True)
        emulator = Emulator(args.twin, 9600)
        period_s = LIBGRIPPER_CYCLE_BYTES * 10 / 9600 * 1.15
        try:
            rc, out = run_client(
                [str(client), emulator.pty, str(args.gripper_cycles), f"{period_s:.5f}"],
                None,
                args.gripper_cycles * period_s * 2 + 120,
            )
        finally:
            time.sleep(0.3)
            emulator.stop()
        counts = emulator.loop_counts()
        empty = out.count("Empty response")
        checks.append((f"libgripper: initialize() returned true (exit {rc})", "initialize=true" in out))
        checks.append(
            (
                f"libgripper: RealTime blocks per LOOP (velocity, position): {counts}",
                len(counts) >= 2 and min(counts[:2]) >= args.gripper_cycles,
            )
        )
        checks.append((f"libgripper: {empty} 'Empty response'", empty == 0 and "Parsing Error" not in out))

    print("\n=== checks ===")
    for text, ok in checks:
        print(f"{'PASS' if ok else 'FAIL'}  {text}")
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
