"""BH8-262 wire format: the manual's examples, round trips, and fuzzing where only the protocol's
declared errors may escape (10,000 cases per parser per run)."""

import contextlib

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from twin.hardware.bh262.protocol import (
    ErrorFlag,
    Feedback,
    FeedbackFormatError,
    HandCommandError,
    ProtocolError,
    RealTimeConfig,
    ReplyFormatError,
    WireOptions,
    decode_control,
    decode_feedback,
    encode_control,
    encode_feedback,
    format_command,
    format_error,
    format_reply,
    parse_reply,
    split_reply,
)

FUZZ = settings(max_examples=10_000, deadline=None)
OPTIONS = st.sampled_from([WireOptions(), WireOptions(line_end=b"\r\n"), WireOptions(temperature_bytes=2)])


def test_manual_example_fget():
    raw = b"1FGET P\n\r1234\n\r=> "
    assert parse_reply(raw, "1FGET P").integers() == [1234]
    assert format_reply("1FGET P", ["1234"]) == raw
    assert format_command("1FGET P") == b"1FGET P\r"


def test_reply_without_result_and_bare_prompt():
    assert parse_reply(b"HI\n\r=> ", "HI").lines == ()
    assert parse_reply(b"=> ", "").lines == ()


def test_err_reply_names_every_flag():
    with pytest.raises(HandCommandError) as info:
        parse_reply(format_error("4M 9000", 128 + 16), "4M 9000")
    err = info.value
    assert err.code == 144
    assert err.flags == ErrorFlag.INVALID_VALUE | ErrorFlag.COULD_NOT_REACH_POSITION
    assert "INVALID_VALUE" in str(err) and "COULD_NOT_REACH_POSITION" in str(err) and "4M 9000" in str(err)


def test_unknown_err_bits_are_reported_not_dropped():
    err = HandCommandError(8 + 32)
    assert err.flags == ErrorFlag.UNKNOWN_COMMAND
    assert "unknown bits 0x8" in str(err)


def test_manual_realtime_examples():
    # 123LOOP with LCV+LCPG and LFS+LFAP: C + 6 bytes out, * + 9 bytes back.
    cfg = RealTimeConfig(motors=(1, 2, 3), control=("LCV", "LCPG"), feedback=("LFS", "LFAP"))
    assert len(encode_control(cfg, {"LCV": [1, -2, 3], "LCPG": [10, 10, 10]})) == 1 + 6
    assert cfg.feedback_size == 1 + 9
    # 1234LOOP with LFV+LFAP: * + 12 bytes back.
    assert RealTimeConfig(motors=(1, 2, 3, 4), feedback=("LFV", "LFAP")).feedback_size == 1 + 12


def test_feedback_fields_are_big_endian_in_manual_order():
    cfg = RealTimeConfig(motors=(1, 2), control=(), feedback=("LFAP", "LFS"))  # given out of order
    assert cfg.feedback == ("LFS", "LFAP")
    fb = decode_feedback(
        cfg, b"*" + bytes([135]) + (17000).to_bytes(2, "big") + bytes([140]) + (5).to_bytes(2, "big")
    )
    assert fb.fields == {"LFS": [135, 140], "LFAP": [17000, 5]}


def test_lct_cannot_mix_with_velocity_control():
    with pytest.raises(ValueError, match="LCT"):
        RealTimeConfig(control=("LCT", "LCV"))


def test_wire_limit_matches_the_formula():
    cfg = RealTimeConfig(motors=(1, 2, 3, 4), control=("LCV", "LCPG"), feedback=("LFV", "LFS", "LFAP"))
    cycle_bytes = 1 + cfg.control_size + cfg.feedback_size
    assert cfg.wire_limit_hz(38400) == pytest.approx(38400 / (10 * cycle_bytes))


printable_line = st.text(
    alphabet=st.characters(min_codepoint=0x20, max_codepoint=0x7E), min_size=0, max_size=40
).filter(lambda s: "=> " not in s and not s.startswith("ERR"))
command = st.text(
    alphabet=st.characters(min_codepoint=0x21, max_codepoint=0x7E), min_size=1, max_size=20
).filter(lambda s: "=> " not in s)


@pytest.mark.slow
@FUZZ
@given(command, st.lists(printable_line, max_size=4), OPTIONS)
def test_reply_round_trip(cmd, lines, options):
    lines = [line for line in lines if line]
    reply = parse_reply(format_reply(cmd, lines, options), cmd, options)
    assert reply.echo == cmd and list(reply.lines) == lines


@pytest.mark.slow
@FUZZ
@given(st.binary(max_size=200), st.sampled_from(["HI", "1FGET P", "C", ""]), OPTIONS)
def test_fuzz_parse_reply_only_declared_errors(raw, cmd, options):
    with contextlib.suppress(ProtocolError):
        parse_reply(raw, cmd, options)


@pytest.mark.slow
@FUZZ
@given(st.binary(max_size=300))
def test_fuzz_split_reply_only_declared_errors(raw):
    try:
        parts = split_reply(raw)
    except ReplyFormatError:
        return
    if parts is not None:
        head, tail = parts
        assert head.endswith(b"=> ") and head + tail == raw


motors = st.lists(st.integers(1, 4), min_size=1, max_size=4, unique=True).map(lambda m: tuple(sorted(m)))
control = st.sampled_from([(), ("LCV",), ("LCPG",), ("LCV", "LCPG"), ("LCT",)])
feedback = st.lists(st.sampled_from(["LFV", "LFS", "LFAP", "LFDP", "LFBP", "LFAIN"]), unique=True).map(tuple)
configs = st.builds(
    RealTimeConfig,
    motors=motors,
    control=control,
    feedback=feedback,
    temperature=st.booleans(),
    options=OPTIONS,
)
RANGES = {"LCV": (-128, 127), "LCPG": (0, 255), "LCT": (-32768, 32767), "LFV": (-128, 127), "LFS": (0, 255),
          "LFAP": (0, 65535), "LFDP": (-128, 127), "LFBP": (0, 65535), "LFAIN": (0, 255)}  # fmt: skip


@pytest.mark.slow
@FUZZ
@given(configs, st.data())
def test_realtime_blocks_round_trip(cfg, data):
    n = len(cfg.motors)
    ctrl = {f: data.draw(st.lists(st.integers(*RANGES[f]), min_size=n, max_size=n)) for f in cfg.control}
    block = encode_control(cfg, ctrl)
    assert len(block) == 1 + cfg.control_size
    assert decode_control(cfg, block[1:]) == ctrl
    fields = {f: data.draw(st.lists(st.integers(*RANGES[f]), min_size=n, max_size=n)) for f in cfg.feedback}
    temp_range = (0, 255) if cfg.options.temperature_bytes == 1 else (-32768, 32767)
    temperature = data.draw(st.integers(*temp_range)) if cfg.temperature else None
    fb = decode_feedback(cfg, encode_feedback(cfg, Feedback(fields, temperature)))
    assert fb.fields == fields and fb.temperature == temperature


@pytest.mark.slow
@FUZZ
@given(configs, st.binary(max_size=40))
def test_fuzz_decode_feedback_only_declared_errors(cfg, raw):
    try:
        fb = decode_feedback(cfg, raw)
    except FeedbackFormatError:
        return
    assert set(fb.fields) == set(cfg.feedback)
    assert all(len(v) == len(cfg.motors) for v in fb.fields.values())


@pytest.mark.slow
@FUZZ
@given(configs, st.binary(max_size=40))
def test_fuzz_decode_control_only_declared_errors(cfg, raw):
    with contextlib.suppress(FeedbackFormatError):
        decode_control(cfg, raw)
