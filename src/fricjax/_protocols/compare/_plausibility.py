"""The fit's advice put in the command line's terms (`command_line_advice`); what is implausible in a fitted
physics model is `_estimation.loop._plausibility.implausible` (`Solution.summary()` reads it too)."""

from __future__ import annotations


def command_line_advice(message: str) -> str:
    """A fit's message with its advice put in terms of `fricjax compare`'s options (the command line has no
    learning rate)."""
    message = message.replace("raise `steps`", "raise --steps")  # the neural recipes say --neural-steps first
    return message.replace("lower the learning rate", "try other starts (--seed, --starts) or more steps (--steps)")
