"""Subcommand registration (skeleton, replaced by the area's owner)."""


def register(subparsers) -> None:
    return None
