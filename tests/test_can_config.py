"""python-can's conventions for the CAN force sensor: channel (port as its alias), the
interface's own keyword arguments, and python-can's own configuration when the file names
neither interface nor channel. All on python-can's virtual interface."""

from __future__ import annotations

import itertools
import re

import can
import pytest

from admittance.daemon import config
from admittance.drivers import optoforce as of
from admittance.drivers.can_sensor import CanForceReader, split_into_can_payloads
from admittance.drivers.force_reader import SampleBuffer, create_sensor
from admittance.errors import ConfigError

from test_daemon_config import error_of, minimal, write

_channels = itertools.count()


@pytest.fixture
def channel() -> str:
    return f"can-config-{next(_channels)}"


def _stream_one(channel: str, reader_section: dict) -> CanForceReader:
    """Open the reader from a [sensor] section, send one sample on ``channel``, check it arrives."""
    buffer = SampleBuffer()
    sender = can.Bus(interface="virtual", channel=channel, ignore_config=True)
    try:
        with create_sensor({"kind": "can", "counts_per_newton": [100.0] * 3, **reader_section}, buffer) as reader:
            for payload in split_into_can_payloads(of.encode_sample(0, 0, (100, 200, 300))):
                sender.send(can.Message(arbitration_id=0x100, data=payload, is_extended_id=False))
            assert buffer.wait_for(1, timeout=10)
            return reader
    finally:
        sender.shutdown()


def test_channel_and_interface_options_reach_can_bus(channel):
    reader = _stream_one(channel, {"interface": "virtual", "channel": channel,
                                   "can_options": {"receive_own_messages": True, "preserve_timestamps": True}})
    assert reader.channel == channel and reader.options["preserve_timestamps"] is True


def test_port_is_an_alias_of_channel(channel):
    assert _stream_one(channel, {"interface": "virtual", "port": channel}).channel == channel


def test_pythoncan_configuration_is_used_when_the_file_names_neither(channel, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "virtual")
    monkeypatch.setenv("CAN_CHANNEL", channel)
    reader = _stream_one(channel, {})
    assert reader.use_can_config and reader.interface is None


def test_the_environment_is_ignored_when_the_file_names_a_channel(channel, monkeypatch):
    monkeypatch.setenv("CAN_INTERFACE", "no-such-interface")
    _stream_one(channel, {"interface": "virtual", "channel": channel})


@pytest.mark.parametrize("options, message", [
    ({"bitrate": 500_000}, r"\[sensor\].bitrate"),
    ({"channel": "can1"}, r"\[sensor\].channel"),
    ({"state": [1, 2]}, "expected a string, number or boolean"),
    ({"x": float("nan")}, "finite"),
    ({f"k{i}": 1 for i in range(40)}, "at most 32"),
])
def test_bad_can_options_are_refused(tmp_path, options, message):
    doc = minimal()
    doc["sensor"] = {"kind": "can", "interface": "virtual", "channel": "c", "lever_arm": 0.1, "can_options": options}
    assert re.search(message, error_of(tmp_path, doc))


def test_channel_and_port_must_agree_and_interface_needs_a_channel(tmp_path):
    doc = minimal()
    doc["sensor"] = {"kind": "can", "channel": "can0", "port": "can1", "lever_arm": 0.1}
    assert "alias of channel" in error_of(tmp_path, doc)
    doc["sensor"] = {"kind": "can", "interface": "pcan", "lever_arm": 0.1}
    assert "channel: required with interface" in error_of(tmp_path, doc)
    doc["sensor"] = {"kind": "can", "lever_arm": 0.1}  # python-can's configuration decides
    assert config.load_config(write(tmp_path, doc)).sensor.interface == ""


def test_reserved_options_are_refused_by_the_reader_too():
    with pytest.raises(ConfigError, match="can_id"):
        CanForceReader("c", 1.0, SampleBuffer(), interface="virtual", options={"can_filters": []})
