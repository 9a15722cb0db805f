"""Run the facestats benchmarks and print one line per benchmark.

Usage::

    python benchmarks/run.py            # every benchmark
    python benchmarks/run.py physics    # the benchmarks of one module (bench_physics.py)
    python benchmarks/run.py --list

Each ``bench_*.py`` module next to this file exposes ``BENCHMARKS``, a list of
``(name, function)``; a function runs its workload and returns a dict of figures
(the first key is the headline).  Timings live here, never in unit tests.
"""

from __future__ import annotations

import argparse
import importlib.util
import pathlib
import sys
import time

HERE = pathlib.Path(__file__).resolve().parent


def _modules():
    for path in sorted(HERE.glob("bench_*.py")):
        spec = importlib.util.spec_from_file_location(path.stem, path)
        mod = importlib.util.module_from_spec(spec)
        sys.modules[path.stem] = mod
        spec.loader.exec_module(mod)
        yield path.stem[len("bench_") :], mod


def _fmt(v):
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("groups", nargs="*", help="benchmark modules to run (default: all)")
    ap.add_argument("--list", action="store_true", help="list the benchmarks and exit")
    args = ap.parse_args(argv)
    known = {path.stem[len("bench_") :] for path in HERE.glob("bench_*.py")}
    unknown = sorted(set(args.groups) - known)
    if unknown:
        print(
            f"run.py: unknown group(s) {', '.join(unknown)}; the groups are {', '.join(sorted(known))}", file=sys.stderr
        )
        return 2
    failed = 0
    for group, mod in _modules():
        if args.groups and group not in args.groups:
            continue
        for name, fn in mod.BENCHMARKS:
            if args.list:
                print(f"{group}.{name}")
                continue
            t0 = time.perf_counter()
            try:
                figures = fn()
            except Exception as exc:  # report and go on with the next benchmark
                print(f"{group}.{name}: FAILED {type(exc).__name__}: {exc}", flush=True)
                failed += 1
                continue
            wall = time.perf_counter() - t0
            body = "  ".join(f"{k}={_fmt(v)}" for k, v in figures.items())
            print(f"{group}.{name}: {body}  [wall {wall:.1f} s]", flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
