"""The `tearcloth` command: `bench` (speed, as JSON) and `demo` (the main job, end to end)."""
from __future__ import annotations

import argparse
import sys


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv[:1] == ["bake"]:
        # bake_cli parses its own arguments, so every bad input ends in one line and exit 2
        from .bake_cli import main as bake

        return bake(argv[1:])
    p = argparse.ArgumentParser(prog="tearcloth", description="Tear Cloth: tearing cloth for Blender and haptics")
    sub = p.add_subparsers(dest="command", required=True)
    b = sub.add_parser("bench", help="measure step times (medians) and write JSON")
    b.add_argument("--json", metavar="PATH", help="write results to this JSON file (merged with what it holds)")
    b.add_argument("--steps", type=int, default=200, help="steps per measurement (default 200)")
    b.add_argument("--scenarios", default="cloth,banknote,tshirt", help="comma-separated: cloth,banknote,tshirt")
    b.add_argument("--no-collision", action="store_true", help="skip the collision experiment")
    b.add_argument("--parts", default="table1,collision,servo,blender,scaling",
                   help="comma-separated parts to run (default: all): table1,collision,servo,blender,scaling")
    b.add_argument("--markdown", metavar="PATH", help="also write a BENCHMARKS.md-style report here")
    b.add_argument("--plots", metavar="DIR", help="write plots (scaling) into this folder")
    k = sub.add_parser("clusters", help="picture of the cluster decomposition (the paper's Fig. 2)")
    k.add_argument("--out", default="clusters.png", help="PNG path (default clusters.png)")
    k.add_argument("--scenario", default="tshirt", choices=("cloth", "banknote", "tshirt"))
    k.add_argument("--cluster-size", type=int, default=100, help="vertices per cluster (default 100)")
    sub.add_parser("bake", add_help=False,
                   help="bake the Tear Cloth objects of a .blend headless (see: tearcloth bake --help)")
    d = sub.add_parser("demo", help="bake the square cloth example (Fig. 1), render it, plot the hand forces")
    d.add_argument("--out", default="tearcloth_demo", help="output folder (default ./tearcloth_demo)")
    args = p.parse_args(argv)
    try:
        if args.command == "bench":
            from .bench import run

            if args.steps < 10:
                p.error("--steps must be at least 10")
            parts = [s.strip() for s in args.parts.split(",") if s.strip()]
            run(args.json, [s.strip() for s in args.scenarios.split(",") if s.strip()], args.steps,
                collision=not args.no_collision, parts=parts, markdown=args.markdown, plots_dir=args.plots)
        elif args.command == "clusters":
            from .bench import cluster_picture

            if args.cluster_size < 4:
                p.error("--cluster-size must be at least 4")
            print(f"wrote {cluster_picture(args.out, args.scenario, args.cluster_size)}")
        elif args.command == "demo":
            from .bake_cli import demo

            demo(args.out)
    except (ValueError, OSError) as e:
        print(f"tearcloth {args.command}: error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
