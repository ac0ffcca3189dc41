"""Prompt text, number encodings and reply parsing (pure logic, plus GPT-4 token counts)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from benchmark.llm.encodings import ENCODINGS, get_encoding
from benchmark.llm.prompt_inputs import OBSERVATIONS, select
from benchmark.llm.prompt import PARTS, PromptConfig, build_prompt, describe_robot
from benchmark.llm.replies import gbnf_grammar, json_schema, parse_reply
from robots import UnknownNameError, load_robot


@pytest.mark.parametrize("name", list(ENCODINGS))
def test_every_encoding_inverts_to_its_resolution(name):
    enc = get_encoding(name)
    values = np.random.default_rng(0).uniform(enc.low, enc.high, 200)
    numbers = [float(n) for n in enc.encode(values)[1:-1].split(",")]
    np.testing.assert_allclose(enc.decode(numbers), values, atol=enc.resolution / 2 + 1e-9)
    if enc.integer_range is not None:
        low, high = enc.integer_range
        assert all(float(n).is_integer() and low <= n <= high for n in numbers)


def test_default_encoding_maps_to_0_200_and_the_paper_code_to_0_100():
    assert ENCODINGS["E5"].encode([-10, 0, 10]) == "[0, 100, 200]"
    assert ENCODINGS["E4"].encode([-5, 0.53, 5]) == "[0, 55, 100]"  # int((round(x, 1) + 5) * 10)
    assert ENCODINGS["E1"].encode([-1.234]) == "[-1.23]" and ENCODINGS["E2"].encode([-1.234]) == "[8.77]"


@pytest.mark.parametrize("compact, wide", [("E5c", "E5"), ("E4c", "E4")])
def test_a_compact_layout_round_trips_every_value_it_can_write(compact, wide):
    """Every integer the compact variant can write decodes and re-encodes to itself, reads back as its wide twin
    does, and a list of them is what its grammar and regex (the reply constraint) accept and the parser reads."""
    import re

    from benchmark.llm.replies import reply_regex

    enc, twin = get_encoding(compact), get_encoding(wide)
    low, high = enc.integer_range
    every = np.arange(low, high + 1)
    decoded = enc.decode(every.astype(float))
    assert [int(n) for n in enc.encode(decoded)[1:-1].split(",")] == every.tolist()
    np.testing.assert_array_equal(decoded, twin.decode(every.astype(float)))
    for chunk in np.array_split(every, len(every) // 12):
        chunk = chunk[:12]
        text = enc.encode(enc.decode(chunk.astype(float)))
        assert " " not in text and text.count(",") == 11
        assert re.fullmatch(reply_regex(enc), text) and not re.fullmatch(reply_regex(twin), text)
        np.testing.assert_array_equal(parse_reply("Output: " + text, enc), enc.decode(chunk.astype(float)))
    assert '("," num){11}' in gbnf_grammar(enc) and '("," " " num){11}' in gbnf_grammar(twin)
    assert "[n1,...,n12]" in describe_robot(load_robot("a1"), PromptConfig(encoding=compact))


def test_observation_choices_select_the_paper_groups():
    assert [len(select(k)) for k in OBSERVATIONS] == [0, 6, 24, 30, 33]
    with pytest.raises(UnknownNameError, match="valid: O1, O2, O3, O4, O5"):
        select("O9")


def test_parse_reply_accepts_only_twelve_numbers():
    enc = ENCODINGS["E5"]
    twelve = "[" + ", ".join(["100"] * 11 + ["120"]) + "]"
    np.testing.assert_allclose(parse_reply(twelve, enc), [0.0] * 11 + [2.0])
    assert parse_reply(" Output: " + twelve + " trailing", enc) is not None
    assert parse_reply("[100, 100]", enc) is None
    assert parse_reply("I think the robot should walk", enc) is None
    assert parse_reply("[" + ", ".join(["100"] * 12) + ", 7]", enc) is None
    assert parse_reply("[100, , 100]", enc) is None
    assert parse_reply(json.dumps({"output": [100] * 12}), enc) is not None


def test_grammar_and_schema_cover_the_encoding_range():
    assert '"200"' in gbnf_grammar(ENCODINGS["E5"]) and "{11}" in gbnf_grammar(ENCODINGS["E5"])
    assert gbnf_grammar(ENCODINGS["E3"]).count('"-"?') == 1
    schema = json_schema(ENCODINGS["E4"])["schema"]["properties"]["output"]
    assert (schema["minItems"], schema["maxItems"], schema["items"]["maximum"]) == (12, 12, 100)


def test_description_parts_switch_on_and_off():
    robot = load_robot("anymal")
    full = describe_robot(robot, PromptConfig())
    assert "ANYmal C" in full and "Kp 200" in full and "FR, FL, RR, RL" in full
    without = describe_robot(robot, PromptConfig(parts=tuple(p for p in PARTS if p != "joints")))
    assert "Joint order" in full and "Joint order" not in without
    assert describe_robot(robot, PromptConfig(parts=())) == ""
    with pytest.raises(ValueError, match="unknown prompt part 'jokes'"):
        PromptConfig(parts=("jokes",))


def test_prompt_ends_with_the_current_input_awaiting_output():
    cfg = PromptConfig(history=2, observation="O2")
    pairs = [(np.zeros(33), np.zeros(12)), (np.ones(33), np.ones(12))]
    text = build_prompt("DESCRIPTION", pairs, np.full(33, 0.5), cfg)
    lines = text.splitlines()
    assert lines[0] == "DESCRIPTION" and lines[-1] == "Output:"
    assert lines[-2] == "Input: [105, 105, 105, 105, 105, 105]"
    assert text.count("Input:") == 3 and lines[-3] == "Output: [110, 110, 110, 110, 110, 110, 110, 110, 110, 110, 110, 110]"


@pytest.mark.parametrize("observation", ["O1", "O5"])
@pytest.mark.parametrize("strategy", ["chronological", "nearest-only"])
def test_the_chat_layout_sends_the_whole_description_as_the_system_message(strategy, observation):
    """The paper's chat layout splits a prompt at its examples (or its current input when it shows none): the system
    message is the description, all five parts, though the io part itself begins "Input: ..."."""
    from benchmark.llm.prompt import split_prompt

    cfg = PromptConfig(history=2, observation=observation, strategy=strategy)
    description = describe_robot(load_robot("a1"), cfg)
    pairs = [(np.zeros(33), np.zeros(12)), (np.ones(33), np.ones(12))]
    for shown in (pairs, []):
        system, user = split_prompt(build_prompt(description, shown, np.full(33, 0.5), cfg, demonstrations=pairs))
        assert system == description and user.endswith("Output:") and "Joint order" not in user


@pytest.mark.parametrize("history,paper", [(0, 348), (10, 1738), (30, 4518), (50, 7298)])
def test_gpt4_prompt_size_is_within_15_percent_of_the_paper(history, paper):
    out = subprocess.run([sys.executable, "-m", "benchmark.cli", "prompt", "--robot", "a1", "--history", str(history),
                          "--tokenizer", "gpt-4", "--json"], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    result = json.loads(out.stdout)
    assert result["prompt"].count("Input: [") == history + 1
    assert abs(result["tokens"] - paper) / paper < 0.15, result["tokens"]
