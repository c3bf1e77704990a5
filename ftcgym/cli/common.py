"""Argument types and helpers shared by the subcommands: argparse turns their errors into usage messages."""
from __future__ import annotations

import argparse
import json
from importlib import metadata

from ftcgym.benchmark.backends import int_at_least

positive_int, non_negative_int = int_at_least(1), int_at_least(0)


def package_version() -> str:
    try:
        return metadata.version("ftcgym")
    except metadata.PackageNotFoundError:
        return "unknown"


def add_env_and_detector_arguments(parser, use: str) -> None:
    """--env-kwargs, --detector and --detector-kwargs of a command that flies one scenario's env; `use`: what the
    detector is for ('score', 'show')."""
    parser.add_argument("--env-kwargs", type=json_object, default={}, metavar="JSON",
                        help="JSON object merged (top-level keys) into the scenario's gym.make kwargs")
    parser.add_argument("--detector", metavar="NAME", type=detector_name,
                        help=f"detector to wrap the env with and {use} (default: the scenario's), or MODULE:ATTR")
    parser.add_argument("--detector-kwargs", type=json_object, default={}, metavar="JSON",
                        help="JSON object of detector arguments")


def json_object(text: str) -> dict:
    """A JSON object (keyword arguments)."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError as error:
        raise argparse.ArgumentTypeError(f"invalid JSON ({error})") from None
    if not isinstance(value, dict):
        raise argparse.ArgumentTypeError(f"expected a JSON object of keyword arguments, got {text}")
    return value


def scenario(name: str):
    """A Scenario by name (registered, installed plug-in or MODULE:ATTR)."""
    from ftcgym.benchmark.scenarios import get_scenario
    try:
        return get_scenario(name)
    except (TypeError, ValueError) as error:
        raise argparse.ArgumentTypeError(str(error)) from None


def scenario_name(name: str) -> str:
    """A scenario name that resolves (as `scenario`), kept as given."""
    scenario(name)
    return name


def policy_name(name: str) -> str:
    """A policy name that resolves (built-in, installed plug-in or MODULE:ATTR), kept as given."""
    from ftcgym.agents import POLICIES
    return _resolvable(POLICIES, name)


def detector_name(name: str) -> str:
    """A detector name that resolves (built-in, installed plug-in or MODULE:ATTR), kept as given."""
    from ftcgym.fdd import DETECTORS
    return _resolvable(DETECTORS, name)


def _resolvable(registry, name: str) -> str:
    try:
        registry.load(name)
    except ValueError as error:
        raise argparse.ArgumentTypeError(str(error)) from None
    return name
