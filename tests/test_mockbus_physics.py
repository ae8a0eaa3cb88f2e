"""The simulated horns move by the plant: the firmware's position loop, gravity, a hand.

Waits poll the simulated state until a condition holds or a generous deadline passes; the
assertions are on where the horn goes, never on how fast the machine ran.
"""

from __future__ import annotations

import math

import pytest

sdk = pytest.importorskip("dynamixel_sdk")
_rtcore = pytest.importorskip("admittance._rtcore")

from helpers import MX64_PLANT, sdk_on_mock_bus, wait_until  # noqa: E402

MX64 = MX64_PLANT
P2_TORQUE_ENABLE, P2_GOAL_POSITION, P2_PRESENT_POSITION, P2_PROFILE_VELOCITY = 64, 116, 132, 112
P1_TORQUE_ENABLE, P1_GOAL_POSITION, P1_PRESENT_POSITION = 24, 30, 36
DEADLINE_S = 20.0


def wait_for(condition, deadline_s: float = DEADLINE_S) -> bool:
    return wait_until(condition, timeout=deadline_s)


@pytest.fixture
def started():
    with sdk_on_mock_bus() as open_:
        yield lambda *servos, protocol=2: open_(
            [{"protocol": protocol, "params": dict(MX64), **s} for s in servos], protocol)


def test_torque_on_and_a_goal_drive_the_horn_there(started):
    bus, port, ph = started({"id": 1, "load_inertia": 0.005})
    goal = 2048 + 600
    assert ph.write4ByteTxRx(port, 1, P2_GOAL_POSITION, goal)[0] == sdk.COMM_SUCCESS
    assert ph.write1ByteTxRx(port, 1, P2_TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS

    def near_goal():
        position, result, _ = ph.read4ByteTxRx(port, 1, P2_PRESENT_POSITION)
        return result == sdk.COMM_SUCCESS and abs(position - goal) <= 3 and abs(bus.servo_state(1)["omega"]) < 0.05

    assert wait_for(near_goal)
    state = bus.servo_state(1)
    assert state["torque_enabled"] and state["goal_tick"] == goal
    assert state["theta"] == pytest.approx(600 * 2 * math.pi / 4096, abs=0.01)


def test_profile_velocity_limits_the_approach(started):
    bus, port, ph = started({"id": 1})
    # 10 units × 0.229 rpm ≈ 0.24 rad/s: the horn cannot outrun the profile.
    assert ph.write4ByteTxRx(port, 1, P2_PROFILE_VELOCITY, 10)[0] == sdk.COMM_SUCCESS
    assert ph.write4ByteTxRx(port, 1, P2_GOAL_POSITION, 4000)[0] == sdk.COMM_SUCCESS
    assert ph.write1ByteTxRx(port, 1, P2_TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    peak = 0.0

    def moved_far():
        nonlocal peak
        state = bus.servo_state(1)
        peak = max(peak, abs(state["omega"]))
        return state["theta"] > 0.1

    assert wait_for(moved_far)
    assert peak < 0.35


def test_torque_off_with_a_gravity_load_falls_and_swings_through(started):
    bus, _, _ = started({"id": 1, "load_inertia": 0.01, "gravity_torque": 1.0, "initial_theta": 1.2})
    assert wait_for(lambda: bus.servo_state(1)["theta"] < -0.3), "the horn never swung past the bottom"
    # It settles hanging down, within the friction band |G·sin θ| <= coulomb.
    settled = wait_for(lambda: bus.servo_state(1)["omega"] == 0.0 and abs(bus.servo_state(1)["theta"]) < 0.09)
    assert settled
    assert bus.servo_state(1)["motor_torque"] == 0.0


def test_a_hand_torque_turns_a_free_horn_and_barely_moves_a_held_one(started):
    bus, port, ph = started({"id": 1}, {"id": 2})
    assert ph.write1ByteTxRx(port, 2, P2_TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    bus.set_external_torque(1, 0.3)
    bus.set_external_torque(2, 0.3)
    assert wait_for(lambda: bus.servo_state(1)["theta"] > 1.0)
    held = bus.servo_state(2)
    assert 0.0 < held["theta"] < 0.05  # the position loop's stiffness resists the hand
    assert held["motor_torque"] < 0.0


def test_p1_servo_follows_its_goal(started):
    bus, port, ph = started({"id": 3, "model": "MX-28"}, protocol=1)
    goal = 2048 - 400
    assert ph.write2ByteTxRx(port, 3, P1_GOAL_POSITION, goal)[0] == sdk.COMM_SUCCESS
    assert ph.write1ByteTxRx(port, 3, P1_TORQUE_ENABLE, 1)[0] == sdk.COMM_SUCCESS
    assert wait_for(lambda: abs(ph.read2ByteTxRx(port, 3, P1_PRESENT_POSITION)[0] - goal) <= 4)


def test_context_manager_runs_and_stops_the_thread():
    with _rtcore.MockBus(servos=[{"id": 1, "params": dict(MX64)}], wire_delay=False) as bus:
        assert bus.running
        assert bus.port_path.startswith("/dev/")
        assert wait_for(lambda: bus.stats()["physics_steps"] > 0)
    assert not bus.running
    state = bus.servo_state(1)
    assert set(state) >= {"theta", "omega", "goal_tick", "present_tick"}
    assert bus.register(1, "Model Number") == 311


def test_unknown_ids_in_python_calls_are_config_errors():
    from admittance.errors import ConfigError

    bus = _rtcore.MockBus(servos=[{"id": 1, "params": dict(MX64)}])
    with pytest.raises(ConfigError, match="no servo with ID 4"):
        bus.set_external_torque(4, 0.1)
    with pytest.raises(ConfigError, match="no control-table item"):
        bus.register(1, "Colour")


def test_stop_while_another_thread_drives_the_hand():
    import threading

    bus = _rtcore.MockBus(servos=[{"id": 1, "params": dict(MX64)}])
    bus.start()
    errors = []

    def hand():
        try:
            for k in range(2000):
                bus.set_external_torque(1, 0.01 * (k % 7))
                bus.servo_state(1)
        except Exception as exc:  # noqa: BLE001 - the test reports whatever escaped
            errors.append(exc)

    worker = threading.Thread(target=hand)
    worker.start()
    bus.stop()
    worker.join()
    assert errors == []
    assert not bus.running
