"""ROBOTIS's own dynamixel-sdk drives the simulated bus as it would real MX servos.

The SDK is the reference client: if its PortHandler/PacketHandler and Group* helpers work on
``MockBus.port_path`` unchanged, any Dynamixel software does. Protocol 2.0 (MX-64(2.0), model
311) and Protocol 1.0 (MX-64, model 310) are both covered, with several servos on one bus.
"""

from __future__ import annotations

import pytest

sdk = pytest.importorskip("dynamixel_sdk")
_rtcore = pytest.importorskip("admittance._rtcore")

from admittance.errors import ConfigError  # noqa: E402
from helpers import MX64_PLANT, sdk_on_mock_bus, wait_until  # noqa: E402

MX64 = MX64_PLANT

# MX(2.0) addresses (protocols.md §3.2).
P2_RETURN_DELAY, P2_TORQUE_ENABLE, P2_LED, P2_HW_ERROR = 9, 64, 65, 70
P2_STATUS_RETURN_LEVEL, P2_GOAL_POSITION, P2_PRESENT_POSITION = 68, 116, 132
P2_PRESENT_VELOCITY, P2_TEMPERATURE, P2_VOLTAGE = 128, 146, 144
# MX (1.0) addresses.
P1_GOAL_POSITION, P1_MOVING_SPEED, P1_PRESENT_POSITION, P1_TORQUE_ENABLE = 30, 32, 36, 24


def servo(servo_id: int, protocol: int = 2, **extra) -> dict:
    return {"id": servo_id, "model": "MX-64", "protocol": protocol, "params": dict(MX64), **extra}


@pytest.fixture
def open_bus():
    """Start a MockBus and an SDK port on it; both are closed after the test."""
    with sdk_on_mock_bus() as open_:
        yield open_


def ok(result, error=0):
    assert result == sdk.COMM_SUCCESS, sdk.PacketHandler(2.0).getTxRxResult(result)
    assert error == 0, f"servo error 0x{error:02X}"


# ---- Protocol 2.0 ---------------------------------------------------------------------------


def test_ping_answers_model_311_and_absent_ids_stay_silent(open_bus):
    bus, port, ph = open_bus([servo(1)])
    model, result, error = ph.ping(port, 1)
    ok(result, error)
    assert model == 311
    _, result, _ = ph.ping(port, 7)
    assert result == sdk.COMM_RX_TIMEOUT
    assert bus.stats()["absent_ids"] == 1


def test_reads_of_every_width_see_the_control_table(open_bus):
    _, port, ph = open_bus([servo(1)])
    rdt, result, error = ph.read1ByteTxRx(port, 1, P2_RETURN_DELAY)
    ok(result, error)
    assert rdt == 250
    model, result, error = ph.read2ByteTxRx(port, 1, 0)
    ok(result, error)
    assert model == 311
    position, result, error = ph.read4ByteTxRx(port, 1, P2_PRESENT_POSITION)
    ok(result, error)
    assert position == 2048  # hanging down at rest
    volts, result, error = ph.read2ByteTxRx(port, 1, P2_VOLTAGE)
    ok(result, error)
    assert volts == 120
    temperature, result, error = ph.read1ByteTxRx(port, 1, P2_TEMPERATURE)
    ok(result, error)
    assert temperature == 25


def test_writes_are_stored_and_rules_give_the_servo_errors(open_bus):
    _, port, ph = open_bus([servo(1)])
    ok(*ph.write1ByteTxRx(port, 1, P2_LED, 1))
    assert ph.read1ByteTxRx(port, 1, P2_LED)[0] == 1
    # Undefined address: Access Error, for reads and writes.
    assert ph.read1ByteTxRx(port, 1, 14)[2] == 0x07
    assert ph.write1ByteTxRx(port, 1, 14, 1)[1] == 0x07
    # Read-only item.
    assert ph.write4ByteTxRx(port, 1, P2_PRESENT_POSITION, 5)[1] == 0x07
    # Out of range: Data Range Error.
    assert ph.write1ByteTxRx(port, 1, P2_TORQUE_ENABLE, 2)[1] == 0x04
    # Half of a 4-byte item: Data Length Error.
    assert ph.write2ByteTxRx(port, 1, P2_GOAL_POSITION, 100)[1] == 0x05
    # Beyond Max Position Limit (4095) in position mode: Data Limit Error.
    assert ph.write4ByteTxRx(port, 1, P2_GOAL_POSITION, 5000)[1] == 0x06
    # EEPROM is locked while torque is on.
    ok(*ph.write1ByteTxRx(port, 1, P2_RETURN_DELAY, 0))
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE_ENABLE, 1))
    assert ph.write1ByteTxRx(port, 1, P2_RETURN_DELAY, 10)[1] == 0x07
    assert ph.read1ByteTxRx(port, 1, P2_RETURN_DELAY)[0] == 0


def test_unknown_instruction_answers_instruction_error(open_bus):
    _, port, ph = open_bus([servo(1)])
    # 0x8A Fast Sync Read is not in MX(2.0)'s instruction set; to one ID it is simply unknown.
    _, result, error = ph.txRxPacket(port, [0, 0, 0, 0, 1, 3, 0, 0x77, 0, 0])
    assert result == sdk.COMM_SUCCESS
    assert error == 0x02


def test_status_return_level_silences_writes_but_not_ping(open_bus):
    _, port, ph = open_bus([servo(1, registers={"Status Return Level": 0})])
    ok(*ph.ping(port, 1)[1:])
    result = ph.read1ByteTxRx(port, 1, P2_LED)[1]
    assert result == sdk.COMM_RX_TIMEOUT
    # The write happens even though no status comes back.
    assert ph.write1ByteTxOnly(port, 1, P2_LED, 1) == sdk.COMM_SUCCESS
    assert ph.write1ByteTxRx(port, 1, P2_STATUS_RETURN_LEVEL, 2)[0] == sdk.COMM_RX_TIMEOUT
    assert ph.read1ByteTxRx(port, 1, P2_LED)[0] == 1


def test_group_sync_write_and_sync_read_with_several_servos(open_bus):
    bus, port, ph = open_bus([servo(1), servo(2), servo(3)])
    writer = sdk.GroupSyncWrite(port, ph, P2_GOAL_POSITION, 4)
    goals = {1: 1000, 2: 2000, 3: 3000}
    for dxl_id, goal in goals.items():
        assert writer.addParam(dxl_id, list(goal.to_bytes(4, "little")))
    assert writer.txPacket() == sdk.COMM_SUCCESS
    reader = sdk.GroupSyncRead(port, ph, P2_GOAL_POSITION, 4)
    for dxl_id in (3, 1, 2):
        assert reader.addParam(dxl_id)
    assert reader.txRxPacket() == sdk.COMM_SUCCESS
    for dxl_id, goal in goals.items():
        assert reader.isAvailable(dxl_id, P2_GOAL_POSITION, 4)
        assert reader.getData(dxl_id, P2_GOAL_POSITION, 4) == goal
        assert bus.servo_state(dxl_id)["goal_tick"] == goal


def test_group_bulk_read_mixes_items_and_servos(open_bus):
    _, port, ph = open_bus([servo(1), servo(2, initial_theta=0.5)])
    reader = sdk.GroupBulkRead(port, ph)
    assert reader.addParam(1, 0, 2)
    assert reader.addParam(2, P2_PRESENT_POSITION, 4)
    assert reader.txRxPacket() == sdk.COMM_SUCCESS
    assert reader.getData(1, 0, 2) == 311
    assert abs(reader.getData(2, P2_PRESENT_POSITION, 4) - (2048 + 0.5 * 4096 / 6.283185307)) < 30


def test_broadcast_ping_lists_every_servo(open_bus):
    _, port, ph = open_bus([servo(5), servo(2), servo(9)])
    found, result = ph.broadcastPing(port)
    assert result == sdk.COMM_SUCCESS
    assert sorted(found) == [2, 5, 9]
    assert all(model == 311 for model, _firmware in found.values())


def test_reboot_is_answered_then_the_servo_boots_and_comes_back_without_the_error(open_bus):
    bus, port, ph = open_bus([servo(1, reboot_time_s=1.0)])
    ok(*ph.write1ByteTxRx(port, 1, P2_TORQUE_ENABLE, 1))
    bus.set_hardware_error(1, 0x20)  # overload
    status, result, error = ph.read1ByteTxRx(port, 1, P2_HW_ERROR)
    assert result == sdk.COMM_SUCCESS
    assert status == 0x20 and error & 0x80
    assert ph.read1ByteTxRx(port, 1, P2_TORQUE_ENABLE)[0] == 0  # overload is in the Shutdown mask
    result, error = ph.reboot(port, 1)
    assert result == sdk.COMM_SUCCESS and error == 0x80, "answered as it was, then it boots"
    assert wait_until(lambda: ph.ping(port, 1)[1] == sdk.COMM_SUCCESS)
    assert bus.stats()["silent_drops"] >= 1, "the pings of its boot second went unanswered"
    status, result, error = ph.read1ByteTxRx(port, 1, P2_HW_ERROR)
    ok(result, error)
    assert status == 0


def test_reg_write_action_clear_and_factory_reset(open_bus):
    bus, port, ph = open_bus([servo(1, initial_theta=7.0)])
    ok(*ph.regWriteTxRx(port, 1, P2_LED, 1, [1]))
    assert ph.read1ByteTxRx(port, 1, P2_LED)[0] == 0
    # Broadcast, as usual: the SDK does not read the status a unicast ACTION gets back.
    assert ph.action(port, sdk.BROADCAST_ID) == sdk.COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 1, P2_LED)[0] == 1
    assert ph.read4ByteTxRx(port, 1, P2_PRESENT_POSITION)[0] > 4095  # a turn and more
    ok(*ph.clearMultiTurn(port, 1))
    assert 0 <= ph.read4ByteTxRx(port, 1, P2_PRESENT_POSITION)[0] <= 4095
    ok(*ph.write1ByteTxRx(port, 1, P2_RETURN_DELAY, 3))
    ok(*ph.factoryReset(port, 1, 0x01))
    assert ph.read1ByteTxRx(port, 1, P2_RETURN_DELAY)[0] == 250
    assert bus.register(1, "ID") == 1


def test_a_changed_id_answers_under_the_new_id(open_bus):
    _, port, ph = open_bus([servo(1)])
    ok(*ph.write1ByteTxRx(port, 1, 7, 4))
    assert ph.ping(port, 4)[0] == 311
    assert ph.ping(port, 1)[1] == sdk.COMM_RX_TIMEOUT


# ---- Protocol 1.0 ---------------------------------------------------------------------------


def test_p1_ping_read_write(open_bus):
    bus, port, ph = open_bus([servo(1, protocol=1)], protocol=1)
    model, result, error = ph.ping(port, 1)
    ok(result, error)
    assert model == 310
    assert ph.ping(port, 3)[1] == sdk.COMM_RX_TIMEOUT
    ok(*ph.write2ByteTxRx(port, 1, P1_GOAL_POSITION, 1500))
    goal, result, error = ph.read2ByteTxRx(port, 1, P1_GOAL_POSITION)
    ok(result, error)
    assert goal == 1500
    assert ph.read2ByteTxRx(port, 1, P1_PRESENT_POSITION)[0] == 2048
    # P1 has one bit for a refused value or address: Range (0x08).
    assert ph.write1ByteTxRx(port, 1, P1_TORQUE_ENABLE, 7)[1] == 0x08
    assert ph.write2ByteTxRx(port, 1, P1_PRESENT_POSITION, 7)[1] == 0x08
    assert bus.stats()["table_errors"] == 2


def test_p1_sync_write_reaches_several_servos(open_bus):
    bus, port, ph = open_bus([servo(1, protocol=1), servo(2, protocol=1)], protocol=1)
    writer = sdk.GroupSyncWrite(port, ph, P1_GOAL_POSITION, 4)
    targets = {1: (1024, 100), 2: (3000, 200)}
    for dxl_id, (goal, speed) in targets.items():
        assert writer.addParam(dxl_id, list(goal.to_bytes(2, "little") + speed.to_bytes(2, "little")))
    assert writer.txPacket() == sdk.COMM_SUCCESS
    for dxl_id, (goal, speed) in targets.items():
        assert ph.read2ByteTxRx(port, dxl_id, P1_GOAL_POSITION)[0] == goal
        assert ph.read2ByteTxRx(port, dxl_id, P1_MOVING_SPEED)[0] == speed


def test_p1_bulk_read(open_bus):
    # The SDK's GroupBulkRead calls P1 bulkReadTx with a wrong signature (SDK 4.x), so drive
    # the packet handler directly, the same bytes GroupBulkRead would send: (len, id, addr)...
    _, port, ph = open_bus([servo(1, protocol=1), servo(2, protocol=1)], protocol=1)
    param = [2, 1, 0, 2, 2, P1_PRESENT_POSITION]
    assert ph.bulkReadTx(port, param, len(param)) == sdk.COMM_SUCCESS
    model, result, error = ph.readRx(port, 1, 2)
    ok(result, error)
    position, result, error = ph.readRx(port, 2, 2)
    ok(result, error)
    assert int.from_bytes(bytes(model), "little") == 310
    assert int.from_bytes(bytes(position), "little") == 2048


def test_p1_reboot_is_an_instruction_error(open_bus):
    _, port, ph = open_bus([servo(1, protocol=1)], protocol=1)
    _, result, error = ph.txRxPacket(port, [0, 0, 1, 2, 0x08, 0])
    assert result == sdk.COMM_SUCCESS
    assert error & 0x40


# ---- configuration --------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("servos", "message"),
    [
        ([], "at least one servo"),
        ([servo(1), servo(1)], "twice"),
        ([servo(1), servo(2, protocol=1)], "same protocol"),
        ([servo(1, model="AX-12")], "unknown servo model"),
        ([servo(1, colour="red")], "unknown servo key"),
        ([{**servo(1), 5: "five"}], "keys must be strings"),
        ([{"id": 1, "params": {"motor_inertia": 0.01, "dampnig": 0.1}}], "unknown plant parameter"),
        ([{"id": 1}], "params"),
        ([servo(1, registers={"Return Delay Time": 300})], "Return Delay Time"),
        ([servo(1, friction="viscous")], "friction"),
    ],
)
def test_bad_configurations_raise_config_error(servos, message):
    with pytest.raises(ConfigError, match=message):
        _rtcore.MockBus(servos=servos)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"servos": [1]}, "each servo must be a table"),
        ({"servos": {"id": 1}}, "list of servo tables"),
        ({"servos": [servo(1)], "baudrate": -5}, "baudrate"),
        ({"servos": [servo(1)], "physics_rate_hz": 0.0}, "physics_rate_hz"),
        ({"servos": [servo(1, protocol=3)]}, "protocol must be 1 or 2"),
        ({"servos": [servo(1, gravity_torque="heavy")]}, "gravity_torque"),
    ],
)
def test_bad_arguments_raise_config_error(kwargs, message):
    with pytest.raises(ConfigError, match=message):
        _rtcore.MockBus(**kwargs)
