"""`twin compare`: two runs of one scenario, stream by stream and finger by finger."""

from __future__ import annotations

import argparse
import json

from twin.validation import run_dir


def add_parser(sub: argparse._SubParsersAction) -> None:
    """Declare the command and its options."""
    p = sub.add_parser("compare", help="compare two runs of one scenario (e.g. sim vs hardware)")
    p.add_argument("run_a", type=run_dir(), metavar="DIR_A", help="reference run (e.g. the sim backend's)")
    p.add_argument(
        "run_b", type=run_dir(), metavar="DIR_B", help="the run compared with it (e.g. the hardware's)"
    )
    p.add_argument("--json", action="store_true", help="print the comparison as JSON")


def cmd_compare(args: argparse.Namespace) -> int:
    """`twin compare A B`: same streams and units? finger positions after time alignment."""
    from twin.compare import contact_windows_s, describe, position_agreement, stream_mismatches

    mismatches = stream_mismatches(args.run_a, args.run_b)
    agreement = position_agreement(args.run_a, args.run_b)
    settled = position_agreement(args.run_a, args.run_b, exclude_s=contact_windows_s(args.run_a))
    if args.json:
        print(
            json.dumps(
                {
                    "mismatches": [vars(m) for m in mismatches],
                    "lag_s": agreement.lag_s,
                    "max_error_counts": agreement.max_error_counts.tolist(),
                    "rms_error_counts": agreement.rms_error_counts.tolist(),
                    "travel_counts": agreement.travel_counts.tolist(),
                    "max_relative_error": agreement.max_relative_error,
                    "max_relative_error_outside_contact": settled.max_relative_error,
                },
                indent=2,
            )
        )
        return 0
    if mismatches:
        for m in mismatches:
            print(f"differs: {m.stream}.{m.field}: {m.a} vs {m.b}")
    else:
        print("streams and units: the same (hand, command, tactile where both have it)")
    print("finger positions: " + describe(agreement))
    worst = settled.max_relative_error
    print(f"  outside the grasp (first contact to compression, +-0.25 s): worst {worst:.2%} of travel")
    return 0


command = cmd_compare
