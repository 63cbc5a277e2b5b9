"""Subcommands for training, evaluation, the studies and falsification; registered on the CLI's parser.

arguments: the argument types; training: train, evaluate, play, demo; study: reproduce, transfer; falsify.
"""

from __future__ import annotations

from highway_srl.commands import falsify, study, training
from highway_srl.commands.arguments import (  # noqa: F401 - the argument types, imported from here by the CLI
    adversary_name, level, levels, non_negative, non_negative_float, positive, positive_float, profile_name,
    seed_list, seed_number, step_form_args,
)
from highway_srl.commands.training import train_config  # noqa: F401


def add_parsers(sub, scenario_args) -> None:
    """Register the subcommands on the CLI's subparsers; scenario_args(p) adds --scenario, --traffic and --adversarial."""
    training.add_parsers(sub, scenario_args)
    study.add_parsers(sub)
    falsify.add_parsers(sub)
