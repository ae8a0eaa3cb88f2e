"""How the wizard talks to the person at the bench: a terminal, a script, or a simulated hand.

Every physical action (let the arm hang, push it, press the handle) is one :meth:`act` call
with a short name and the instruction; the wizard reads the devices once it returns. A
terminal waits for Enter; a script (``--yes``) waits ``settle`` seconds, for a helper who
follows printed instructions; the simulated bench's hand does the action itself.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import Protocol, TextIO

from admittance.errors import ConfigError



class Prompter(Protocol):
    def say(self, text: str) -> None: ...

    def act(self, action: str, instruction: str) -> None: ...

    def confirm(self, question: str) -> bool: ...


class TerminalPrompter:
    """Interactive: instructions on the terminal, Enter when done."""

    def __init__(self, out: TextIO = sys.stderr, read: Callable[[str], str] = input):
        self.out, self.read = out, read

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def act(self, action: str, instruction: str) -> None:
        self.say(instruction)
        try:
            self.read("  press Enter when done (Ctrl-C aborts) ")
        except EOFError:
            raise ConfigError("no answer on standard input: run with --yes to follow the steps by time") from None

    def confirm(self, question: str) -> bool:
        try:
            return self.read(f"{question} [y/N] ").strip().lower() in ("y", "yes")
        except EOFError:
            return False


class ScriptedPrompter:
    """``--yes``: every question answered yes, each action given ``settle`` seconds."""

    def __init__(self, settle: float, out: TextIO = sys.stderr, sleep: Callable[[float], None] = time.sleep):
        self.settle, self.out, self.sleep = settle, out, sleep

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    def act(self, action: str, instruction: str) -> None:
        self.say(f"{instruction} (--yes: {self.settle:g} s)")
        self.sleep(self.settle)

    def confirm(self, question: str) -> bool:
        self.say(f"{question} yes (--yes)")
        return True
