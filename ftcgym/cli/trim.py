"""`ftcgym trim`: steady level-flight trims of a quad-plane parameter set over airspeed (markdown table)."""
from __future__ import annotations

from .common import json_object


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser("trim", help="quad-plane trims over airspeed (markdown table)",
                                   description="Steady level-flight trims of a quad-plane parameter set over "
                                               "airspeed: mode, skew, angle of attack, elevator, pusher, hover "
                                               "rotors, wing lift.")
    parser.add_argument("--vehicle", default="vsqp", help="quad-plane parameter set (default vsqp)")
    parser.add_argument("--vehicle-overrides", type=json_object, default=None, metavar="JSON",
                        help="JSON object of parameter overrides")
    parser.add_argument("--airspeeds", type=float, nargs="+", default=None, metavar="V",
                        help="airspeeds in m/s (default: hover to 24 m/s)")
    parser.set_defaults(run=run)


def run(args, argv: list[str]) -> int:
    from ftcgym.agents.quadplane_trim import default_airspeeds, format_trim_table, trim_table
    from ftcgym.models.vsqp import make_vsqp_params

    params = make_vsqp_params(args.vehicle, args.vehicle_overrides)
    print(format_trim_table(trim_table(params, args.airspeeds or default_airspeeds(params))))
    return 0
