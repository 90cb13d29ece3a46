#!/usr/bin/env python
"""Run every benchmark of iplanner_torch and print (and optionally save) its figures.

Each area's benchmark lives in ``scripts/bench_<area>.py`` and exposes ``run(quick) -> dict``
mapping figure names to ``{"value": number, "unit": text, ...}``; speed figures carry the
reference they were measured against in the same run (``reference``, ``ratio``).

Usage::

    python scripts/bench.py                       # full run, prints a table
    python scripts/bench.py --quick               # reduced sizes (a smoke run)
    python scripts/bench.py --json experiments/bench/cpu.json --force  # replace the record
    python scripts/bench.py --only collision,robot

``--json`` refuses a file that exists (and its ``.meta.json``), before any benchmark runs,
unless ``--force`` is given: a stored record is replaced only on purpose; a path it could
not write (under a file, in a read-only folder) is refused then too. Each area's figures
are printed as it ends; an interrupt (Ctrl-C or SIGTERM) prints those measured so far, writes
no JSON and exits 130.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import platform
import signal
import sys
import time
import traceback
from pathlib import Path

import torch

from iplanner_torch.errors import IPlannerError

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))  # the bench modules share scripts/_timing.py
from _report import commit_short, refuse_stored_json  # noqa: E402

AREAS = ("dtw", "prediction", "robot", "collision", "planning", "sim", "sweep")


def _load(area: str):
    path = HERE / f"bench_{area}.py"
    if not path.exists():
        return None
    spec = importlib.util.spec_from_file_location(f"bench_{area}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


def _fmt(v: object) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


#: keys of a figure that hold the number it was measured against in the same run
_REFERENCE_VALUES = ("reference_s", "reference_ms", "reference_us", "reference_pairs_per_s")


def reference_text(fig: dict) -> str:
    """What a figure was measured against, for the table: its reference (a number, with
    ``reference_name`` when given, or what the reference is) and ratio; a figure measured
    against no reference in the run shows its goal, or ``(absolute)``."""
    parts = []
    ref = fig.get("reference")
    numeric = next((fig[k] for k in _REFERENCE_VALUES if k in fig), None)
    if isinstance(ref, int | float) and not isinstance(ref, bool):
        parts.append(f"ref {_fmt(ref)}")
    elif numeric is not None:
        parts.append(f"ref {_fmt(numeric)}")
    if isinstance(ref, str):
        parts.append(f"against {ref}")
    elif "reference_name" in fig:
        parts.append(f"({fig['reference_name']})")
    if "ratio" in fig:
        parts.append(f"ratio {_fmt(fig['ratio'])}")
    if not parts:
        return f"goal {_fmt(fig['goal'])}" if "goal" in fig else "(absolute)"
    return "  ".join(parts)


def print_figures(figures: dict[str, dict]) -> None:
    """The table of ``figures``: name, value, unit and :func:`reference_text`."""
    width = max((len(k) for k in figures), default=10)
    print(f"{'figure'.ljust(width)}  {'value':>12}  unit          reference / ratio")
    for name, fig in figures.items():
        value = _fmt(fig.get("value"))
        unit = str(fig.get("unit", ""))
        print(f"{name.ljust(width)}  {value:>12}  {unit:<12}  {reference_text(fig)}", flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick", action="store_true", help="reduced sizes (CI smoke run)")
    parser.add_argument("--json", type=Path, default=None, help="write the figures as JSON")
    parser.add_argument(
        "--force",
        action="store_true",
        help="replace an existing --json file and its .meta.json (stored results)",
    )
    parser.add_argument("--only", default=None, help="comma-separated areas: " + ",".join(AREAS))
    parser.add_argument("--threads", type=int, default=None, help="torch.set_num_threads (>= 1)")
    args = parser.parse_args(argv)
    areas = list(AREAS)
    if args.only is not None:
        areas = [a.strip() for a in args.only.split(",") if a.strip()]
        unknown = [a for a in areas if a not in AREAS]
        if unknown or not areas:
            what = f"unknown area(s) {', '.join(unknown)}" if unknown else "no area"
            parser.error(f"--only {args.only!r}: {what}; the areas are {', '.join(AREAS)}")
    if args.threads is not None and args.threads < 1:
        parser.error(f"--threads must be >= 1, got {args.threads}")
    if args.json is not None and args.json.is_dir():
        parser.error(f"--json {args.json} is a folder; give the JSON file to write")
    refuse_stored_json(args.json, args.force)
    if args.threads is not None:
        torch.set_num_threads(args.threads)
    figures: dict[str, dict] = {}
    failed: list[str] = []
    # SIGTERM (timeout, a job scheduler) stops the run as Ctrl-C does: the figures measured
    # so far are printed rather than lost
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)
    try:
        for area in areas:
            module = _load(area)
            if module is None:
                print(f"[{area}] no benchmark module, skipped", flush=True)
                continue
            print(f"[{area}] running{' (quick)' if args.quick else ''} ...", flush=True)
            t0 = time.perf_counter()
            try:
                result = module.run(quick=args.quick)
            except IPlannerError as err:  # a bad input (IPLANNER_PREDICTOR): one line
                print(f"[{area}] error: {type(err).__name__}: {err}", file=sys.stderr, flush=True)
                failed.append(area)
                continue
            except Exception:  # noqa: BLE001 - report and continue with the other areas
                traceback.print_exc()
                failed.append(area)
                continue
            print(f"[{area}] done in {time.perf_counter() - t0:.1f} s", flush=True)
            print_figures(result)  # each area's figures as soon as they are measured
            figures.update(result)
    except KeyboardInterrupt:
        print()
        if figures:
            print_figures(figures)
        kept = f"; {args.json} not written" if args.json is not None else ""
        print(
            f"interrupted in area {area!r}: {len(figures)} figure(s) above{kept}",
            file=sys.stderr,
        )
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    print()
    print_figures(figures)
    if args.json is not None:
        if not figures:
            print(f"error: no figure was produced; {args.json} not written", file=sys.stderr)
            return 2
        meta = {
            "command": "python scripts/bench.py " + " ".join(argv or sys.argv[1:]),
            "commit": commit_short() or "unknown",
            "quick": args.quick,
            "torch": torch.__version__,
            "threads": torch.get_num_threads(),
            "cpu": platform.processor() or platform.machine(),
            "cuda": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
            "failed_areas": failed,
        }
        meta_path = args.json.with_suffix(".meta.json")
        try:
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(figures, indent=2) + "\n")
            meta_path.write_text(json.dumps(meta, indent=2) + "\n")
        except OSError as err:  # the figures of a long run are printed rather than lost
            print(json.dumps(figures, indent=2))
            print(f"error: {type(err).__name__}: {err} (the figures are above)", file=sys.stderr)
            return 2
        print(f"\nwrote {args.json} and {meta_path}")
    return 1 if failed else 0


if __name__ == "__main__":
    raise SystemExit(main())
