"""Helper for the SIGKILL test: writes a wall-clock-paced 200 Hz stream until it is killed.

Usage: python _killed_writer.py RUN_DIR. Sample i has t_s = i / 200 and is appended no earlier than
that much wall time after the start time stored in the run metadata ("start_wall_time_s").
"""

import sys
import time

from twin.recording import FieldSpec, RunWriter, StreamSpec

RATE_HZ = 200.0
SAFETY_STOP_S = 30.0  # the test kills us long before this; never run forever


def main(run_dir: str) -> None:
    """Append paced samples until killed (or until SAFETY_STOP_S, then close)."""
    start = time.time()
    writer = RunWriter(run_dir, {"start_wall_time_s": start}, flush_interval_s=0.25)
    spec = StreamSpec(
        name="fast",
        rate_hz=RATE_HZ,
        fields={
            "index": FieldSpec(unit="1", dtype="int64", kind="status"),
            "xyz": FieldSpec(unit="m", shape=(3,)),
        },
    )
    writer.add_stream(spec)
    i = 0
    while i / RATE_HZ < SAFETY_STOP_S:
        t = i / RATE_HZ
        delay = start + t - time.time()
        if delay > 0:
            time.sleep(delay)
        writer.append("fast", t, {"index": i, "xyz": [t, 2 * t, 3 * t]})
        i += 1
    writer.close()


if __name__ == "__main__":
    main(sys.argv[1])
