"""A live change of parameters (``admittance set``, ``<prefix>/params``), checked like the file.

The names are the configuration's keys, and so are the checks: a set passes exactly what a
configuration file with those values would pass, with the same reasons.

1. Each name (``[<id>.][limits.]key``) is looked up among the configuration's live keys. A
   key of the configuration that is not live (``rate_hz``, ``zero_tick``) is refused and says
   so; an unknown one gets a did-you-mean.
2. Each value is checked against its key's metadata (``schema.check_value``: type, finite,
   range), under the name the request used.
3. The candidate, that is the loop's current values with every change applied, goes through
   the rule functions the configuration uses (``config.check_joint_params``,
   ``config.check_loop_params``): limits in order and within the servo's reach, a stable
   virtual joint, a compensation only on a joint whose parameter file has a servo model, a
   low-pass below half the rate.

Only a request that passes all three reaches the loop, which checks it once more against its
own envelope (rtcore/rt/src/params.rs) before publishing it whole.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from admittance._rtcore import split_param_name
from admittance.daemon.config import (
    ALL_KEYS, JOINT_LIVE, LOOP_LIVE, DaemonConfig, check_joint_params, check_loop_params, has_servo_model,
    reachable_range,
)
from admittance.daemon.schema import check_value, clip, did_you_mean
from admittance.errors import ConfigError


class LiveParams:
    """The live-set gate of one running configuration."""

    def __init__(self, cfg: DaemonConfig) -> None:
        self.joints = {j.id: j for j in cfg.joints}
        self.rate_hz = cfg.loop.rate_hz

    def check(self, request: Mapping[str, Any], current: Mapping[str, Any]) -> dict[str, Any]:
        """The request, its values normalised, if it may go to the loop; else ConfigError(reason).

        ``current`` is the loop's ``params()``: ``"<id>.<key>"`` per joint, loop-wide keys bare.
        """
        joints = {jid: {k: current[f"{jid}.{k}"] for k in JOINT_LIVE if f"{jid}.{k}" in current}
                  for jid in self.joints}
        loop = {k: current[k] for k in LOOP_LIVE if k in current}
        out = {}
        for name, value in request.items():
            targets, key = self.parse_name(name)
            meta = (JOINT_LIVE if targets else LOOP_LIVE)[key][1]
            out[name] = value = check_value(meta, value, clip(name))
            for jid in targets:
                joints[jid][key] = value
            if not targets:
                loop[key] = value
        for jid, values in joints.items():
            joint = self.joints[jid]
            check_joint_params(values, reach=reachable_range(joint), has_servo=has_servo_model(joint),
                               rate_hz=self.rate_hz, where=f"joint {jid}", name=lambda k, jid=jid: f"{jid}.{k}")
        check_loop_params(loop, rate_hz=self.rate_hz, where="loop", name=str)
        return out

    def parse_name(self, name: str) -> tuple[list[int], str]:
        """(the joint ids a name sets, its key); no ids for a loop-wide key. ConfigError says why not."""
        if not isinstance(name, str):
            raise ConfigError(f"parameter names are strings, got {clip(repr(name))}")
        try:
            joint_id, key = split_param_name(name)  # the loop's own parser of [id.][limits.]key
        except ValueError:
            joint_id, key = -1, ""
        if joint_id is not None and joint_id not in self.joints:
            head = name.partition(".")[0]
            raise ConfigError(f"{clip(name)}: no joint with id {clip(head)} (joints: {sorted(self.joints)})")
        if key in JOINT_LIVE:
            return ([joint_id] if joint_id is not None else list(self.joints)), key
        if key in LOOP_LIVE:
            if joint_id is not None:
                raise ConfigError(f"{clip(name)}: {key} is loop-wide and takes no joint id")
            return [], key
        if key in ALL_KEYS:
            tables = ALL_KEYS[key]
            where = " and ".join(f"[{table}].{key}" for table in tables)
            raise ConfigError(f"{clip(name)}: {where} {'is' if len(tables) == 1 else 'are'} not live: read once "
                              "at start (change the configuration and restart the daemon)")
        raise ConfigError(f"unknown parameter {clip(name)!r}{did_you_mean(key, [*JOINT_LIVE, *LOOP_LIVE])}")
