"""``freebody list``: the bundled cases with their description and truth kind."""
from __future__ import annotations

ORDER = 10

import textwrap


def add_parser(sub) -> None:
    p = sub.add_parser("list", help="list the bundled cases")
    p.add_argument("--names", action="store_true", help="print the case names only")


def run(args) -> int:
    from ..input.casefile import bundled_case_paths, load_case
    from ..reference_impl.truth import truth_kind

    rows = []
    for name in bundled_case_paths():
        pb = load_case(name)
        rows.append((name, truth_kind(pb), pb.description))
    if args.names:
        print("\n".join(r[0] for r in rows))
        return 0
    w = max(len(r[0]) for r in rows)
    print(f"{'case':<{w}}  {'truth':<11}  description")
    for name, truth, desc in rows:
        lines = textwrap.wrap(desc, 100 - w - 15) or [""]
        print(f"{name:<{w}}  {truth:<11}  {lines[0]}")
        for extra in lines[1:]:
            print(f"{'':<{w}}  {'':<11}  {extra}")
    return 0
