"""Any object the CLI's validator accepts either builds and steps, or is refused in one line (ConfigError):
never another exception (issue 18: `--density 1e-6` was accepted and then crashed MuJoCo's compiler with a
traceback). Values are drawn from the flags' own ranges, edges included, and parsed by the real parser."""

import mujoco
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from twin.cli import _foam_from_args, build_parser
from twin.interface.errors import ConfigError
from twin.sim.scene import build_model


def _accepted(flag: str) -> st.SearchStrategy[float]:
    """Floats the parser accepts for `flag`, read from its own validator (edges drawn often), so that a
    range widened later is fuzzed as widened."""
    sub = next(
        a for a in build_parser()._subparsers._group_actions[0].choices["run"]._subparsers._group_actions
    )
    action = next(a for a in sub.choices["compress"]._actions if flag in a.option_strings)
    rng = action.type.range
    low = rng.min if rng.min_inclusive else float(np.nextafter(rng.min, np.inf))
    high = min(rng.max if rng.max_inclusive else float(np.nextafter(rng.max, -np.inf)), 1e12)
    return st.one_of(st.sampled_from([low, high]), st.floats(low, high, allow_nan=False))


overrides = st.fixed_dictionaries(
    {},
    optional={
        **{
            flag: _accepted(flag) for flag in ("--young", "--poisson", "--damping", "--density", "--friction")
        },
        "--resolution": st.integers(3, 5),  # larger grids accepted too, but cost seconds to compile
        "--dof": st.sampled_from(["trilinear", "quadratic", "full"]),
        "--size-mm": st.tuples(*[_accepted("--size-mm")] * 3),
    },
)


@settings(max_examples=40, deadline=None, derandomize=True, database=None)
@given(st.sampled_from(["block", "cylinder", "sphere"]), overrides)
def test_an_accepted_object_builds_and_steps_or_is_one_line(name: str, flags: dict):
    argv = ["run", "compress", "--object", name]
    for flag, value in flags.items():
        argv += [flag, *map(repr, value)] if isinstance(value, tuple) else [flag, str(value)]
    args = build_parser().parse_args(argv)  # accepted by the validator, or the draw is wrong
    try:
        model = build_model(_foam_from_args(args))
    except ConfigError as exc:
        assert "\n" not in str(exc) and str(exc)
        return
    data = mujoco.MjData(model)
    for _ in range(20):
        mujoco.mj_step(model, data)
    assert np.isfinite(data.time)
