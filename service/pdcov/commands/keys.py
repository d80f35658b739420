"""``pdcov keys new``: an operator key pair for signing re-tasking requests."""

from __future__ import annotations

import argparse
from pathlib import Path


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("keys", help="operator keys that sign re-tasking requests",
                       description="Operator keys (Ed25519): the vehicle's mission lists the "
                                   "public keys it obeys (service.retask_operator_keys).")
    ks = p.add_subparsers(dest="keys_command", metavar="ACTION", required=True)
    n = ks.add_parser("new", help="write DIR/operator.key (mode 0600) and DIR/operator.pub",
                      description="Write a new key pair and print its key id; an existing "
                                  "key is never overwritten.")
    n.add_argument("--out", type=Path, required=True, metavar="DIR", help="folder to write")
    n.set_defaults(func=run_new)


def run_new(args: argparse.Namespace) -> int:
    from pdcov.bus.operator_keys import PRIVATE_NAME, PUBLIC_NAME, write_key_pair

    key = write_key_pair(args.out)
    print(f"key id {key.id}: {args.out / PRIVATE_NAME} (private, keep it on the ground "
          f"station), {args.out / PUBLIC_NAME} (list it in service.retask_operator_keys)")
    return 0
