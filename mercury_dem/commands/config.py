"""``mercury-dem config``: print the default configuration or check a file."""

from __future__ import annotations

import argparse

import yaml

from mercury_dem.config import Config, config_template, to_dict

NAME = "config"
HELP = "print the configuration template, or the effective configuration of --config"


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--template", action="store_true", help="print the full default configuration as commented YAML")


def run(args: argparse.Namespace, config: Config) -> int:
    if args.template:
        print(config_template(), end="")
    else:
        print(yaml.safe_dump(to_dict(config), sort_keys=False), end="")
    return 0
