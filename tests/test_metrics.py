"""Walking metrics on hand-made state sequences, and the reference models on hand-written prompts."""

from __future__ import annotations

import numpy as np
import pytest

from benchmark.trial.cell import CellSpec
from benchmark.trial.trials import run_cell
from benchmark.llm.controller import LLMSettings
from benchmark.llm.encodings import get_encoding
from benchmark.llm.reference import HoldModel, KnnModel, OracleModel, ReplayModel, history_pairs
from benchmark.llm.replies import parse_reply
from benchmark.trial.runner import Walking, first_stop, walking_metrics, window_stopped

DT, PHASE = 0.1, 10.0
STEPS = int(PHASE / DT)


def _metrics(x, yaw=None, fall_after=None, command=1.0):
    yaw = np.zeros(len(x)) if yaw is None else yaw
    return walking_metrics(np.asarray(x), np.asarray(yaw), fall_after, PHASE, DT, command)


def test_standing_is_not_walking():
    m = _metrics(np.zeros(STEPS + 1))
    assert m["nwt"] == 0.0 and not m["success"] and m["upright_fraction"] == 1.0


def test_walking_at_the_command_is_full_marks():
    m = _metrics(np.arange(STEPS + 1) * DT * 1.0)
    assert m["nwt"] == 1.0 and m["success"] and m["stop_time"] is None


def test_circling_walks_but_the_heading_change_shows_it():
    # 1 m/s along a circle of radius 1.6 m: the forward progress along x swings back and forth
    t = np.arange(STEPS + 1) * DT
    yaw = t / 1.6
    x = 1.6 * np.sin(yaw)
    m = _metrics(x, yaw)
    assert m["heading_change_rad"] == pytest.approx(PHASE / 1.6)  # unwrapped: more than a full turn
    assert not m["success"] and m["nwt"] < 0.5


def test_falling_ends_walking_time_at_the_fall():
    x = np.arange(41) * DT  # walked 4 s, then fell
    m = _metrics(x, fall_after=4.0)
    assert m["nwt"] == pytest.approx(0.4) and m["upright_fraction"] == pytest.approx(0.4) and not m["success"]


def test_stopping_midway_ends_walking_time_at_the_stop():
    x = np.concatenate([np.arange(51) * DT, np.full(50, 5.0)])  # walks 5 s, then stands 5 s, upright
    m = _metrics(x)
    window = Walking().window_s
    assert not m["success"] and m["upright_fraction"] == 1.0
    # the first window that fails starts once too little of it is walking
    assert 5.0 - window < m["stop_time"] <= 5.0 and m["nwt"] == pytest.approx(m["stop_time"] / PHASE)


def test_slow_walking_short_of_the_distance_is_no_success():
    x = np.arange(STEPS + 1) * DT * 0.3  # 0.3 m/s: walking, but 3 m of the 10 m commanded
    m = _metrics(x)
    assert m["nwt"] == 1.0 and not m["success"]


def test_a_phase_shorter_than_the_window_is_judged_whole():
    assert first_stop(np.array([0.0, 0.1, 0.2]), DT, 2.0, 0.2) is None
    assert first_stop(np.array([0.0, 0.0, 0.01]), DT, 2.0, 0.2) == 0.0


def test_the_stop_seen_step_by_step_is_the_first_stop_of_the_whole_phase():
    """`--end-at-stop` checks each new window as the trial runs: the first slow one it sees is the one `first_stop`
    finds over the whole phase, so a trial ended there keeps its NWT and success. Random walks that slow, stall,
    back off and walk on."""
    rng, window, speed = np.random.default_rng(3), Walking().window_s, 0.2
    for _ in range(200):
        x = np.concatenate([[0.0], np.cumsum(np.abs(rng.normal(0.1, 0.08, STEPS)) * rng.choice([1, 0, -0.5], STEPS,
                                                                                                  p=[0.8, 0.15, 0.05]))])
        seen = next((i for i in range(1, len(x) + 1) if window_stopped(list(x[:i]), DT, window, speed)), None)
        stop = first_stop(x, DT, window, speed)
        if stop is None:
            assert seen is None
        else:  # the window starting at the stop ends at the step it is seen
            assert seen is not None and seen - 1 == int(round(stop / DT)) + int(round(window / DT))


E5 = get_encoding("E5")
PROMPT = """You control a robot.

Recent inputs and the outputs that kept the robot walking:
Input: [100, 100]
Output: [1, 1, 1]
Input: [110, 90]
Output: [2, 2, 2]
Input: [130, 70]
Output: [3, 3, 3]
Input: [111, 91]
Output:"""


def test_knn_answers_the_output_of_the_nearest_input():
    assert KnnModel().reply_to(PROMPT) == "[2, 2, 2]"


def test_hold_repeats_the_newest_output():
    assert HoldModel().reply_to(PROMPT) == "[3, 3, 3]"


def test_replay_continues_the_gait_cycle():
    outputs = [[1, 1], [5, 5], [9, 9]] * 3
    lines = [f"Input: [{i}]\nOutput: [{a}, {b}]" for i, (a, b) in enumerate(outputs)]
    prompt = "\n".join(["desc", *lines, "Input: [0]", "Output:"])
    assert ReplayModel().reply_to(prompt) == "[1, 1]"  # period 3: the step after [9, 9] is [1, 1]


@pytest.mark.parametrize("prompt", ["", "Output:", "Input: [1, 2]\nOutput:", "garbage\nInput: [x]\nOutput: [oops",
                                    "Input: [1]\nOutput: [1, 2]\nInput: [1, 2, 3]\nOutput:"])
def test_reference_models_fall_back_on_empty_or_malformed_history(prompt):
    for model in (KnnModel(), HoldModel(), ReplayModel()):
        reply = model.reply_to(prompt)
        assert isinstance(reply, str) and reply.startswith("[")  # never a crash


def test_reference_models_read_nothing_but_the_prompt_text():
    """The same text gives the same answer whatever else happened; only the oracle is handed state."""
    for cls in (KnnModel, HoldModel, ReplayModel):
        a, b = cls(), cls()
        b.reply_to("Input: [5]\nOutput: [9, 9, 9]\nInput: [5]\nOutput:")  # b has seen another prompt
        assert a.reply_to(PROMPT) == b.reply_to(PROMPT)
        assert not getattr(cls, "privileged", False)
    assert OracleModel.privileged
    oracle = OracleModel()
    oracle.set_reference(np.array([0.0, 0.5, -1.0]), E5)
    assert parse_reply(" " + oracle.reply_to(PROMPT), E5, 3).tolist() == [0.0, 0.5, -1.0]
    assert history_pairs(PROMPT)[1] == [111.0, 91.0]


def test_standing_and_freezing_score_zero_and_the_oracle_walks():
    stand = run_cell(CellSpec(sim="mujoco", robot="a1", policy="stand", duration=10.0), range(2))
    assert all(not t.success and t.nwt <= 0.1 and t.upright_fraction == 1.0 for t in stand)
    hold = run_cell(CellSpec(policy="llm", duration=20.0, settings=LLMSettings(model="hold")), range(2))
    # a frozen trot may tip over before the phase ends (fewer than its 100 queries): never a success
    assert all(not t.success and 0 < t.policy_metrics["queries"] <= 100 for t in hold)
    oracle = run_cell(CellSpec(policy="llm", duration=20.0, settings=LLMSettings(model="oracle")), range(2))
    assert all(t.success for t in oracle) and oracle[0].policy_metrics["input_tokens"] > 7000
