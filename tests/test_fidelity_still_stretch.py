"""`admittance fidelity` on a session whose first stretch has no motion (the hand had not started).

The wheel smoke's 1-in-3 failure (.ci/wheel_smoke.py, "fidelity"): on a loaded machine the
simulated hand started late, a hold cut the 8 s session in two before it did, and `identify`'s
split (every third segment held out, starting with the second) trained on the still first
stretch alone: "too little motion to identify the model". A still stretch carries nothing for
either fit, so the analysis leaves it out and lists it. The session is the loop oracle's
(tests/oracles/servo.py) written through the daemon's Recorder: two 3 s segments, the hand from
3.2 s.
"""

from __future__ import annotations

import pytest

from oracles.servo import LagOracle, multisine, session


def late_hand(t: float) -> float:
    return 0.0 if t < 3.2 else multisine(t - 3.2)


@pytest.fixture(scope="module")
def late_start(tmp_path_factory):
    folder = tmp_path_factory.mktemp("late_hand")
    session(folder, LagOracle(), seconds=6.0, hand=late_hand)
    return folder


def test_a_still_first_stretch_is_left_out_and_listed(late_start):
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse

    recording = load_recording(late_start)
    names = [s.name for s in recording.of_joint(1)]
    assert len(names) == 2, names  # the still stretch and the moving one: identify would train on the first
    result = analyse(recording)
    assert result["excluded_segments"] == names[:1], result["excluded_segments"]
    assert result["segments"] == names[1:], result["segments"]
    assert result["target_check"]["verdict"]["passed"], result["target_check"]
    assert result["servo"]["time_constant"] > 0


def test_a_recording_without_a_moving_stretch_is_one_clear_line(tmp_path):
    from admittance.errors import DataError
    from admittance.fidelity.recording import load_recording
    from admittance.fidelity.report import analyse

    # Two nudges in each 3 s segment: out and back by 7 mrad, one way in the first, the other
    # way in the second. The recording's own motion check (over the whole joint) sees 13 mrad;
    # neither stretch moved 10 mrad by itself.
    pulses = {0.5: 0.04, 1.5: -0.04, 3.5: -0.04, 4.5: 0.04}
    nudges = lambda t: next((tau for start, tau in pulses.items() if start <= t < start + 0.1), 0.0)  # noqa: E731
    session(tmp_path, LagOracle(), seconds=6.0, hand=nudges)
    recording = load_recording(tmp_path)
    with pytest.raises(DataError, match="moved less than 10 mrad in every stretch"):
        analyse(recording)
