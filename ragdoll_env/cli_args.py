"""argparse types of the command lines built on the environments
(``ragdoll_env.demo``, ``training.*``): a bad value is argparse's usage
error naming the option, before anything runs."""

from __future__ import annotations

import argparse


def int_at_least(low: int):
    """argparse type: an integer >= ``low``."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            value = None
        if value is None or value < low:
            raise argparse.ArgumentTypeError(f"must be an integer >= {low}, got {text!r}")
        return value

    return parse


#: argparse types: an integer >= 1, an integer >= 0
positive_int = int_at_least(1)
non_negative_int = int_at_least(0)
