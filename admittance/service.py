"""``admittance service install``: the systemd unit and the udev rule, from the installed package.

The unit and the rule ship inside the package (``admittance/data/systemd/``), so a lab that
installed the wheel into a venv needs no checkout: the command writes the unit with ``ExecStart``
pointing at the ``admittance`` of the venv it runs from, and copies the udev rule. It starts
nothing: it prints the ``systemctl`` lines to run, so a person decides when the joint goes live.

Two edits of the shipped unit follow from where things are:
- ``--user NAME`` replaces the transient user (``DynamicUser=yes``) with a fixed account, for a
  lab whose configuration or recordings belong to a person;
- a venv or configuration under /home or /root stays readable: ``ProtectHome=yes`` would hide
  it from the service, so it becomes ``ProtectHome=read-only``.
"""

from __future__ import annotations

import argparse
import re
import sys
from dataclasses import dataclass
from pathlib import Path

from admittance import data
from admittance.errors import ConfigError

UNIT_NAME = "admittance.service"
RULE_NAME = "99-admittance-ftdi.rules"
DEFAULT_CONFIG = Path("/etc/admittance/admittance.toml")
HOME_ROOTS = (Path("/home"), Path("/root"), Path("/run/user"))
USER_NAME = re.compile(r"[a-z_][a-z0-9_-]{0,31}\$?")  # useradd's portable names


@dataclass(frozen=True)
class Placement:
    """Where the unit and the rule go (``root`` prefixes both, for tests and image builds)."""

    root: Path = Path("/")

    @property
    def unit(self) -> Path:
        return self.root / "etc/systemd/system" / UNIT_NAME

    @property
    def rule(self) -> Path:
        return self.root / "etc/udev/rules.d" / RULE_NAME


def register(subparsers) -> None:
    service = subparsers.add_parser(
        "service", help="install the daemon as a systemd service (unit + udev rule) from this venv",
        description="Install the systemd unit (for the admittance of this venv) and the FTDI udev rule "
                    "shipped in the package. Nothing is started: the systemctl lines to run are printed "
                    "(systemd/INSTALL.md, docs/daemon.md).")
    actions = service.add_subparsers(dest="service_action", metavar="ACTION", required=True)
    install = actions.add_parser("install", help="write /etc/systemd/system/admittance.service and the udev rule")
    install.add_argument("--user", metavar="NAME", help="run as this account (default: a transient user in dialout)")
    install.add_argument("--config", type=Path, default=DEFAULT_CONFIG, metavar="FILE",
                         help=f"the configuration the service runs (default {DEFAULT_CONFIG})")
    install.add_argument("--root", type=Path, default=Path("/"), metavar="DIR",
                         help="install below DIR instead of / (an image being built)")
    install.add_argument("--print", action="store_true", dest="print_only",
                         help="print the unit to stdout and write nothing")
    install.set_defaults(func=_install_command)


def daemon_executable() -> Path:
    """The ``admittance`` script of the running environment (the venv's bin/)."""
    script = Path(sys.executable).parent / "admittance"
    if not script.is_file():
        raise ConfigError(f"no admittance script beside {sys.executable}: run this command with the "
                          "venv's own admittance (e.g. /opt/admittance/venv/bin/admittance service install)")
    return script.absolute()


def render_unit(executable: Path, config: Path, user: str | None = None) -> str:
    """The shipped unit with ``ExecStart`` for ``executable`` and ``config`` (absolute paths)."""
    for what, path in (("the admittance script", executable), ("--config", config)):
        if not path.is_absolute() or any(c.isspace() or c in "%$\"'\\" for c in str(path)):
            raise ConfigError(f"{what}: {path} must be an absolute path without spaces, quotes or % "
                              "(systemd would split or expand it)")
    text = data.path("systemd", UNIT_NAME).read_text()
    text = _replace(text, "ExecStart", f"{executable} run --config {config}")
    if user is not None:
        if not USER_NAME.fullmatch(user):
            raise ConfigError(f"--user {user!r} is not a valid account name")
        text = _replace(text, "DynamicUser", "no\nUser=" + user)
    if any(path.is_relative_to(home) for path in (executable, config) for home in HOME_ROOTS):
        text = _replace(text, "ProtectHome", "read-only")
    return text


def _replace(text: str, key: str, value: str) -> str:
    new, count = re.subn(rf"^{key}=.*$", f"{key}={value}", text, count=1, flags=re.M)
    if count != 1:  # the shipped unit lost a line this command relies on
        raise AssertionError(f"the packaged {UNIT_NAME} has no {key}= line")
    return new


def install(placement: Placement, config: Path, user: str | None = None) -> list[Path]:
    """Write the unit and the udev rule below ``placement.root``; return the files written."""
    unit = render_unit(daemon_executable(), config.absolute(), user)
    rule = data.path("systemd", RULE_NAME).read_text()
    written = []
    for target, text, mode in ((placement.unit, unit, 0o644), (placement.rule, rule, 0o644)):
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(text)
            target.chmod(mode)
        except PermissionError:
            raise ConfigError(f"cannot write {target}: permission denied (run it with sudo, "
                              f"e.g. sudo {daemon_executable()} service install)") from None
        except OSError as exc:
            raise ConfigError(f"cannot write {target}: {exc.strerror}") from None
        written.append(target)
    return written


def _install_command(args: argparse.Namespace) -> int:
    if args.print_only:
        sys.stdout.write(render_unit(daemon_executable(), args.config.absolute(), args.user))
        return 0
    config = args.config.absolute()
    written = install(Placement(args.root), config, args.user)
    for path in written:
        print(f"wrote {path}")
    if not config.is_file():
        print(f"{config} does not exist yet: admittance setup --out {config} "
              f"(or admittance run --print-example-config > {config}), then check it with "
              f"admittance run --config {config} --check")
    print("next: sudo udevadm control --reload && sudo udevadm trigger --subsystem-match=usb-serial")
    print("      sudo systemctl daemon-reload && sudo systemctl enable --now admittance.service")
    return 0
