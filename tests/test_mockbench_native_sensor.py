"""The mock bench's simulated OptoForce DAQ streaming from Rust (`NativeOptoForce`, dxlsim/src/daq.rs)
against the Python stream it replaces on the daemon's bench: the same frames for the same hand, the
profile tables it is given, and the hand held until the daemon's word."""

from __future__ import annotations

import os
import time

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from admittance.drivers import optoforce as of
from admittance.errors import ConfigError
from admittance.mockbench.bench import BenchConfig, MockBench
from admittance.mockbench.hand import PushRelease, Ramp, Sine, Steps, make_profile, tabulate
from admittance.mockbench.simulated_sensor import NativeOptoForce, SimulatedOptoForce
from helpers import examples, wait_until

RATE_HZ = 1000.0
HAND = "sine:amplitude=0.3,frequency=2"


def read_samples(port: str, n: int, timeout: float = 5.0) -> list[of.Sample]:
    """The first ``n`` samples a host reads from ``port`` (fewer if ``timeout`` passes)."""
    fd = os.open(port, os.O_RDWR | os.O_NONBLOCK)
    parser, samples = of.OptoForceParser(), []
    give_up = time.monotonic() + timeout
    try:
        while len(samples) < n and time.monotonic() < give_up:
            try:
                samples += [r for r in parser.feed(os.read(fd, 4096)) if isinstance(r, of.Sample)]
            except BlockingIOError:
                time.sleep(0.002)
    finally:
        os.close(fd)
    return samples[:n]


@pytest.mark.parametrize("stream", ["python", "rust"])
def test_both_streams_send_the_hand_s_force_on_the_sample_grid(stream):
    """Sample k carries τ(k / rate) as counts (the ForceModel's rule), from either stream, once
    the host opened the port (samples before are dropped, so k starts where it joined)."""
    with MockBench(BenchConfig(profile=HAND, sensor_stream=stream)) as bench:
        kind = NativeOptoForce if stream == "rust" else SimulatedOptoForce
        assert isinstance(bench.sensor, kind)
        samples = read_samples(bench.sensor_port, 200)
        late = bench.sensor.stats()["late_skips"]
    assert len(samples) == 200
    if late:
        pytest.skip(f"the stream fell 100 ms behind ({late} skips): the grid restarted, nothing to compare")
    profile, model = make_profile(HAND), bench.force_model
    for s in samples:
        k = s.counter  # the frame counter: samples since the stream started (mod 2^16)
        expected = round(profile(k / RATE_HZ) / model.lever_arm * model.counts_per_newton[0])
        assert abs(s.counts[0] - expected) <= 1, (stream, k, s.counts[0], expected)


@settings(max_examples=examples(60), deadline=None)
@given(profile=st.one_of(
    st.builds(Sine, amplitude=st.floats(-1, 1), frequency=st.floats(0.05, 20), offset=st.floats(-0.5, 0.5)),
    st.builds(PushRelease, amplitude=st.floats(-1, 1), period=st.floats(0.5, 10), rise=st.floats(0.01, 0.2),
              hold=st.floats(0.0, 0.2), fall=st.floats(0.01, 0.2)),
    st.builds(Ramp, amplitude=st.floats(-1, 1), period=st.floats(0.1, 10), rest=st.floats(0, 2)),
    st.builds(Steps, amplitude=st.floats(-1, 1), step=st.floats(0.01, 3))),
    k=st.integers(0, 10**7))
def test_a_table_reproduces_its_profile_at_the_stream_s_sample_times(profile, k):
    """Linear interpolation of the table at t = k ms (wrapped by its period) is the profile's own
    value there, within the table's step (a smooth profile: its curvature; a step: its instant)."""
    t_tab, tau_tab, period = tabulate(profile, 1e-3)
    assert period is not None and t_tab[0] == 0 and abs(t_tab[-1] - period) < 1e-12
    t = k * 1e-3
    x = t % period
    i = max(1, min(len(t_tab) - 1, next((j for j, tj in enumerate(t_tab) if tj > x), len(t_tab) - 1)))
    y = tau_tab[i - 1] + (tau_tab[i] - tau_tab[i - 1]) * (x - t_tab[i - 1]) / (t_tab[i] - t_tab[i - 1])
    step = period / (len(t_tab) - 1)
    near = [profile(t + d) for d in (-step, -step / 2, 0.0, step / 2, step)]  # the profile itself, unwrapped
    assert min(near) - 1e-9 <= y <= max(near) + 1e-9, (t, y, near)


def sensed(bench, tau: float) -> bool:
    """The sensor reads ``tau`` within 2 s (polled: the stream's next sample shows it)."""
    return wait_until(lambda: bench.sensor.last_torque == pytest.approx(tau), timeout=2.0)


def test_a_python_callable_is_refused_by_the_rust_stream_with_what_to_do():
    with MockBench(BenchConfig(profile="still")) as bench:
        bench.profile = make_profile("still:torque=0.2")  # a built-in: handed over
        assert sensed(bench, 0.2)
        with pytest.raises(ConfigError, match="sensor_stream = 'python'"):
            bench.profile = lambda t: 0.1
    with pytest.raises(ConfigError, match="sensor_stream is one of"):
        MockBench(BenchConfig(sensor_stream="c"))


def test_the_hand_keeps_off_until_the_daemon_s_word():
    with MockBench(BenchConfig(profile="still:torque=0.3")) as bench:
        assert sensed(bench, 0.3)
        bench.sensor.hold_hand()
        assert sensed(bench, 0.0)
        assert bench.bus.servo_state(1)["hand_torque"] == 0.0
        bench.sensor.start_hand(0.0)
        assert sensed(bench, 0.3)
        assert bench.bus.servo_state(1)["hand_torque"] == pytest.approx(0.3), "the horn is pushed too"
        with pytest.raises(ConfigError):
            bench.sensor.start_hand(float("nan"))
